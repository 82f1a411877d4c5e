"""A virtual X display (Xvfb) for the tests of the human experts' windows.

SDL's dummy video driver shows nothing and accepts anything; under Xvfb the window is a real X11
window (fonts drawn, surfaces saved as they look), yet no screen is needed. The `xvfb` fixture
points pygame at a fresh Xvfb for one test; `running_xvfb` starts one for any other use (a CLI
subprocess, with `xvfb_env`).
"""

from __future__ import annotations

import os
import select
import shutil
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager

import pytest

START_TIMEOUT_S = 20


@contextmanager
def running_xvfb() -> Iterator[str]:
    """Starts `Xvfb :N -screen 0 1024x768x24` on a free display N; yields ":N" once it accepts
    connections and kills it afterwards. Skips the test when Xvfb is not installed."""
    if shutil.which("Xvfb") is None:
        pytest.skip("Xvfb not installed: apt-get install xvfb")
    # -displayfd makes Xvfb take the first free display number and write it to the pipe once it
    # listens: no race with another server over the number, no polling for the socket.
    read_end, write_end = os.pipe()
    server = subprocess.Popen(
        ["Xvfb", "-displayfd", str(write_end), "-screen", "0", "1024x768x24", "-nolisten", "tcp"],
        pass_fds=[write_end],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    os.close(write_end)
    try:
        ready, _, _ = select.select([read_end], [], [], START_TIMEOUT_S)
        number = os.read(read_end, 32).decode().strip() if ready else ""
        if not number:
            server.kill()
            raise RuntimeError(f"Xvfb did not start: {server.communicate()[1].decode(errors='replace')[-2000:]}")
        yield f":{number}"
    finally:
        os.close(read_end)
        # A pygame window still open on the server would take the whole process down with it
        # (Xlib's fatal I/O error exits): close the display first.
        pygame = sys.modules.get("pygame")
        if pygame is not None:
            pygame.display.quit()
        server.kill()
        server.wait()


def xvfb_env(display: str) -> dict[str, str]:
    """os.environ for a subprocess that draws on `display`."""
    return {**os.environ, "DISPLAY": display, "SDL_VIDEODRIVER": "x11"}


@pytest.fixture
def xvfb(monkeypatch: pytest.MonkeyPatch) -> Iterator[str]:
    """A fresh Xvfb for one test, with DISPLAY and SDL_VIDEODRIVER=x11 set; yields the display."""
    with running_xvfb() as display:
        monkeypatch.setenv("DISPLAY", display)
        monkeypatch.setenv("SDL_VIDEODRIVER", "x11")
        yield display
