"""The README's screenshot of a person's DAgger window, taken from a real take-over run.

Runs `imitation train dagger --env CartPole-v1 --expert keyboard --mode takeover` in this
process, presses → for steps 3-11 of each episode (pygame key events, as a person's keyboard
sends them) and saves the window while the person holds the controls in round 2.

Usage (a virtual display; Xvfb from `apt-get install xvfb`):
    xvfb-run -s "-screen 0 1024x768x24" .venv/bin/python tools/window_screenshot.py docs/images/dagger-window.png
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

import pygame  # noqa: E402

import cli  # noqa: E402
from imitation.experts.keyboard import KeyboardExpert  # noqa: E402
from imitation.experts.window import ControlStatus  # noqa: E402

HELD = range(3, 12)
SHOT_AT = (2, 8)  # round, step


def main(target: Path) -> None:
    original = KeyboardExpert.show_status
    taken = []

    def show_status(self: KeyboardExpert, status: ControlStatus) -> None:
        if status.step == HELD.start:
            pygame.event.post(pygame.event.Event(pygame.KEYDOWN, key=pygame.K_RIGHT))
        elif status.step in (0, HELD.stop):  # released at the end, or when the episode ended first
            pygame.event.post(pygame.event.Event(pygame.KEYUP, key=pygame.K_RIGHT))
        if (status.round, status.step) == SHOT_AT and not taken:
            self.screenshot(target)  # the frame of the step before, under the strip as it stands
            taken.append(status)
        original(self, status)

    KeyboardExpert.show_status = show_status  # type: ignore[method-assign]
    with tempfile.TemporaryDirectory() as folder:
        code = cli.main(["train", "dagger", "--env", "CartPole-v1", "--expert", "keyboard", "--mode", "takeover", "--rounds", "2",
                         "--episodes-per-round", "2", "--epochs", "5", "--speed", "4", "--quiet", "--out", str(Path(folder) / "run")])
    if code != 0 or not taken:
        raise SystemExit(f"no screenshot: the run exited {code}, or never reached round {SHOT_AT[0]} step {SHOT_AT[1]}")
    print(f"wrote {target}")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else REPO / "docs" / "images" / "dagger-window.png")
