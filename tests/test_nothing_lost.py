"""Nothing lost, nothing overwritten: every writer on a full disk, planted symlinks, FIFOs and
devices at the output, two writers to one output, a killed write's partial file and
`imitation recover`, resuming over changed demos, SIGTERM, and the one-step run swap.

A full disk is simulated with `RLIMIT_FSIZE` (writes past the limit fail with EFBIG, as they
fail with ENOSPC on a full disk: the same code path), which needs no mount and no root;
`test_a_real_full_tmpfs` also fills a real tmpfs when this machine lets the tests mount one."""

from __future__ import annotations

import json
import os
import resource
import shutil
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from support import DATASETS, REPO, run_cli, run_cli_many
from test_crash_safety import interrupt_after_first_checkpoint, start, wait_for

from imitation.data.mcap.reader import DemoFile
from imitation.errors import ImitationError
from imitation.output import OutputLock, create_exclusive, replace_directory


def run_with_file_limit(limit: int, *args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    """`imitation ARGS` in a process that cannot write files beyond `limit` bytes."""

    def limit_files() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # fail the write with EFBIG instead of killing the process
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    return subprocess.run([sys.executable, str(REPO / "cli.py"), *args], capture_output=True, text=True, timeout=timeout, cwd=REPO,
                          preexec_fn=limit_files)


def one_line_error(result: subprocess.CompletedProcess) -> str:
    lines = [line for line in result.stderr.splitlines() if line.strip() and not line.startswith("warning:")]
    assert result.returncode == 1, (result.returncode, result.stderr[-3000:])
    assert "Traceback" not in result.stderr, result.stderr[-3000:]
    assert len(lines) == 1 and lines[0].startswith("error: "), result.stderr[-3000:]
    return lines[0]


def same_episodes(a, b) -> None:
    assert len(a) == len(b)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x.observations, y.observations)
        np.testing.assert_array_equal(x.actions, y.actions)
        np.testing.assert_array_equal(x.rewards, y.rewards)
        assert (x.terminated, x.truncated) == (y.terminated, y.truncated)


# -- a full disk ------------------------------------------------------------------------------


def test_a_full_disk_during_record_keeps_the_finished_episodes_and_recover_makes_them_a_file(tmp_path: Path) -> None:
    out = tmp_path / "new.mcap"
    record = ["record", "--env", "CartPole-v1", "--episodes", "20", "--seed", "5", "--quiet"]
    error = one_line_error(run_with_file_limit(60_000, *record, "--out", str(out)))
    partial = tmp_path / "new.mcap.partial"
    assert f"{out}: cannot write: file too large" in error and f"{partial} keeps " in error and "imitation recover" in error
    kept = int(error.split(" keeps ")[1].split()[0])
    assert kept >= 3 and not out.exists() and partial.is_file()

    # A new record must not truncate what the partial file holds.
    before = partial.read_bytes()
    refused = one_line_error(run_cli(*record, "--out", str(out)))
    assert f"holds {kept} finished episode(s) of an interrupted write" in refused
    assert partial.read_bytes() == before

    recovered = run_cli("recover", str(partial))
    assert recovered.returncode == 0, recovered.stderr
    assert f"recovered {kept} complete episodes" in recovered.stdout and not partial.exists()
    full = tmp_path / "full.mcap"
    assert run_cli(*record, "--out", str(full)).returncode == 0
    same_episodes(list(DemoFile(out)), DemoFile(full).read_episodes(list(range(kept))))


def _npz(path: Path) -> Path:
    rng = np.random.default_rng(0)
    steps = 20_000
    starts = np.zeros(steps, bool)
    starts[::500] = True
    np.savez(path, obs=rng.normal(size=(steps, 4)).astype(np.float32), actions=rng.integers(0, 2, (steps, 1)), rewards=np.ones(steps),
             episode_starts=starts)
    return path


@pytest.mark.parametrize(
    "writer",
    ["convert", "train bc", "train ppo", "export foxglove", "export lerobot"],
)
def test_every_writer_on_a_full_disk_fails_in_one_line_naming_the_output(tmp_path: Path, writer: str) -> None:
    demos = str(DATASETS / "CartPole-v1.mcap")
    out = tmp_path / "out"
    args = {
        "convert": ["convert", str(_npz(tmp_path / "rollouts.npz")), "--out", str(out)],
        "train bc": ["train", "bc", "--demos", demos, "--env", "CartPole-v1", "--epochs", "1", "--quiet", "--out", str(out)],
        "train ppo": ["train", "ppo", "--env", "CartPole-v1", "--steps", "512", "--quiet", "--out", str(out)],
        "export foxglove": ["export", demos, "--to", "foxglove", str(out), "--quiet"],
        "export lerobot": ["export", demos, "--to", "lerobot", str(out), "--quiet"],
    }[writer]
    error = one_line_error(run_with_file_limit(20_000, *args))
    assert str(out) in error and "file too large" in error
    assert not out.exists()
    if writer == "convert":  # each episode is flushed as it is written: the finished ones stay
        partial = tmp_path / "out.partial"
        assert " keeps " in error and len(DemoFile(partial, salvage=True)) >= 1


def _mount_tmpfs(mount: Path, options: str) -> None:
    mount.mkdir()
    if os.geteuid() != 0 or subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(mount)], capture_output=True).returncode != 0:
        pytest.skip("mounting a tmpfs needs root in a machine that allows it (RLIMIT_FSIZE covers the same code path)")


def test_a_read_only_folder(tmp_path: Path) -> None:
    mount = tmp_path / "read-only"
    _mount_tmpfs(mount, "size=1m,ro")
    try:
        demos = str(DATASETS / "CartPole-v1.mcap")
        for args in (["export", demos, "--to", "lerobot", str(mount / "dataset")], ["export", demos, "--to", "foxglove", str(mount / "steps.mcap")],
                     ["record", "--env", "CartPole-v1", "--episodes", "1", "--out", str(mount / "new.mcap")]):
            error = one_line_error(run_cli(*args, "--quiet"))
            assert str(mount) in error and "read-only file system" in error
    finally:
        subprocess.run(["umount", str(mount)], check=False)


def test_a_real_full_tmpfs(tmp_path: Path) -> None:
    mount = tmp_path / "small"
    _mount_tmpfs(mount, "size=1m")
    try:
        (mount / "filler").write_bytes(b"\0" * (1024 * 1024 - 80 * 1024))
        error = one_line_error(run_cli("record", "--env", "CartPole-v1", "--episodes", "40", "--quiet", "--out", str(mount / "new.mcap")))
        assert "no space left on the device (disk full)" in error and " keeps " in error
        assert len(DemoFile(mount / "new.mcap.partial", salvage=True)) >= 1
    finally:
        subprocess.run(["umount", str(mount)], check=False)


# -- what --out names -------------------------------------------------------------------------


def test_a_planted_symlink_at_the_partial_name_is_never_written_through(tmp_path: Path) -> None:
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me")
    for name, args in (
        ("r.mcap", ["record", "--env", "CartPole-v1", "--episodes", "1", "--quiet"]),
        ("c.mcap", ["convert", str(_npz(tmp_path / "rollouts.npz"))]),
    ):
        (tmp_path / f"{name}.partial").symlink_to(victim)
        error = one_line_error(run_cli(*args, "--out", str(tmp_path / name)))
        assert "is a symbolic link; not writing through it" in error
    os.symlink(victim, tmp_path / "f.mcap.partial")
    assert run_cli("export", str(DATASETS / "CartPole-v1.mcap"), "--to", "foxglove", str(tmp_path / "f.mcap"), "--quiet").returncode == 1
    assert victim.read_text() == "keep me"


def test_fifos_and_devices_named_by_out_are_refused_and_left_alone(tmp_path: Path) -> None:
    fifo = tmp_path / "pipe.mcap"
    os.mkfifo(fifo)
    error = one_line_error(run_cli("record", "--env", "CartPole-v1", "--episodes", "1", "--quiet", "--out", str(fifo)))
    assert "is a FIFO; it must be a regular file or a new path" in error
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    error = one_line_error(run_cli("train", "bc", "--demos", str(DATASETS / "CartPole-v1.mcap"), "--env", "CartPole-v1", "--out", str(fifo)))
    assert "is a FIFO; it must be a directory or a new path" in error
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode)


def test_temporaries_are_created_exclusively(tmp_path: Path) -> None:
    (tmp_path / "there").write_text("x")
    os.symlink(tmp_path / "elsewhere", tmp_path / "link")
    for name in ("there", "link"):
        with pytest.raises(ImitationError, match=f"{name}: exists; it was not made by this run"):
            create_exclusive(tmp_path / name)
    assert not (tmp_path / "elsewhere").exists()


# -- two writers ------------------------------------------------------------------------------


def test_a_second_writer_to_the_same_output_fails_at_once_naming_the_first(tmp_path: Path) -> None:
    out = tmp_path / "same.mcap"
    first = start("record", "--env", "CartPole-v1", "--episodes", "100000", "--quiet", "--out", str(out))
    try:
        wait_for(tmp_path / ".same.mcap.lock", first)
        began = time.monotonic()
        second = run_cli("record", "--env", "CartPole-v1", "--episodes", "2", "--quiet", "--out", str(out))
        error = one_line_error(second)
        assert f"{out}: another process (pid {first.pid}, since " in error and "is writing it" in error
        assert time.monotonic() - began < 30
        assert first.poll() is None  # still recording: the second writer did not wait for it
        first.send_signal(signal.SIGINT)
        _, stderr = first.communicate(timeout=120)
    finally:
        if first.poll() is None:
            first.kill()
    assert first.returncode == 130, stderr
    kept = int(stderr.split("kept ")[1].split()[0])
    assert kept >= 1 and len(DemoFile(out, verify=True)) == kept
    assert not (tmp_path / ".same.mcap.lock").exists()


def test_a_second_training_run_into_the_same_directory_fails_at_once(tmp_path: Path) -> None:
    out = tmp_path / "run"
    args = ["train", "bc", "--demos", str(DATASETS / "CartPole-v1.mcap"), "--env", "CartPole-v1", "--epochs", "30", "--quiet", "--out", str(out)]
    first = start(*args)
    try:
        wait_for(tmp_path / "run.partial" / "config.json", first)
        error = one_line_error(run_cli(*args))
        assert f"{out}: another process (pid {first.pid}" in error
        first.send_signal(signal.SIGINT)
        first.communicate(timeout=120)
    finally:
        if first.poll() is None:
            first.kill()


def test_the_lock_is_released_and_taken_again(tmp_path: Path) -> None:
    target = tmp_path / "t.mcap"
    with OutputLock(target):
        with pytest.raises(ImitationError, match=f"another process \\(pid {os.getpid()}, since"):
            OutputLock(target).acquire()
    with OutputLock(target):
        pass


# -- runs -------------------------------------------------------------------------------------


def test_resume_refuses_demos_whose_content_changed(tmp_path: Path) -> None:
    demos = tmp_path / "demos.mcap"
    shutil.copy(DATASETS / "CartPole-v1.mcap", demos)
    out = tmp_path / "bc"
    args = ["train", "bc", "--demos", str(demos), "--env", "CartPole-v1", "--epochs", "200", "--hidden", "16", "--quiet", "--out", str(out)]
    interrupt_after_first_checkpoint(*args, out=out)
    record = run_cli("record", "--env", "CartPole-v1", "--episodes", "3", "--quiet", "--out", str(tmp_path / "other.mcap"))
    assert record.returncode == 0
    shutil.copy(tmp_path / "other.mcap", demos)  # same path, other content
    error = one_line_error(run_cli(*args, "--resume"))
    assert "--resume: the demo files changed since" in error
    error = one_line_error(run_cli(*args))
    assert "holds an interrupted run with a checkpoint; continue it with --resume" in error


def start_ignoring_sigint(*args: str) -> subprocess.Popen:
    """`imitation ARGS` with SIGINT ignored, as a script's background job has it: SIGTERM must
    still stop it."""
    return subprocess.Popen([sys.executable, str(REPO / "cli.py"), *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))


def test_sigterm_stops_a_recording_with_its_finished_episodes(tmp_path: Path) -> None:
    out = tmp_path / "long.mcap"
    process = start_ignoring_sigint("record", "--env", "CartPole-v1", "--episodes", "100000", "--quiet", "--out", str(out))
    try:
        wait_for(tmp_path / "long.mcap.partial", process)
        time.sleep(2)
        process.send_signal(signal.SIGTERM)
        _, stderr = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 130 and "Traceback" not in stderr, stderr[-2000:]
    kept = int(stderr.split("kept ")[1].split()[0])
    assert kept >= 1 and len(DemoFile(out, verify=True)) == kept


def test_sigterm_stops_training_at_a_checkpoint_like_ctrl_c(tmp_path: Path) -> None:
    out = tmp_path / "ppo"
    process = start_ignoring_sigint("train", "ppo", "--env", "CartPole-v1", "--steps", "51200", "--quiet", "--out", str(out))
    try:
        wait_for(tmp_path / "ppo.partial" / "checkpoint" / "state.json", process)
        process.send_signal(signal.SIGTERM)
        _, stderr = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 130 and "Traceback" not in stderr, stderr[-2000:]
    assert "run the same command with --resume to continue" in stderr
    assert (tmp_path / "ppo.partial" / "checkpoint" / "state.json").is_file()


def test_a_finished_run_replaces_the_old_one_in_one_step(tmp_path: Path) -> None:
    old, new = tmp_path / "run", tmp_path / "run.partial"
    old.mkdir()
    (old / "weights").write_text("old")
    new.mkdir()
    (new / "weights").write_text("new")
    replace_directory(new, old)
    assert (old / "weights").read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


def test_an_out_name_that_is_not_utf8_is_written_or_refused_cleanly(tmp_path: Path) -> None:
    name = os.fsencode(tmp_path) + b"/\xff-demos.mcap"
    result = subprocess.run([sys.executable, str(REPO / "cli.py").encode(), b"record", b"--env", b"CartPole-v1", b"--episodes", b"1", b"--quiet",
                             b"--out", name], capture_output=True, timeout=120, cwd=REPO)
    assert b"Traceback" not in result.stderr and result.returncode in (0, 1), result.stderr
    assert not [p for p in os.listdir(os.fsencode(tmp_path)) if p.endswith((b".partial", b".lock"))]
    if result.returncode == 0:
        assert len(DemoFile(os.fsdecode(name))) == 1


def test_results_take_the_permissions_the_umask_allows(tmp_path: Path) -> None:
    """Under umask 027 every result is rw-r----- (folders rwxr-x---), as a new file is: also
    the weights (safetensors writes through a private temporary) and a LeRobot export's videos
    of several episodes (lerobot concatenates them through one)."""

    commands = [
        ["record", "--env", "CartPole-v1", "--expert", "scripted", "--episodes", "3", "--pixels", "32x32", "--quiet", "--out",
         str(tmp_path / "pixels.mcap")],
        ["export", str(tmp_path / "pixels.mcap"), "--to", "lerobot", str(tmp_path / "lerobot")],
        ["train", "bc", "--demos", str(DATASETS / "CartPole-v1.mcap"), "--epochs", "1", "--quiet", "--out", str(tmp_path / "bc")],
    ]
    script = "import json, sys, cli\nsys.exit(max(cli.main(argv) for argv in json.loads(sys.argv[1])))"
    result = subprocess.run([sys.executable, "-c", script, json.dumps(commands)], capture_output=True, text=True, timeout=300,
                            cwd=REPO, preexec_fn=lambda: os.umask(0o027))
    assert result.returncode == 0, result.stderr
    assert list(tmp_path.glob("lerobot/videos/*/*/*.mp4")) and (tmp_path / "bc" / "model.safetensors").is_file()
    for path in tmp_path.rglob("*"):
        expected = 0o750 if path.is_dir() else 0o640
        assert stat.S_IMODE(path.stat().st_mode) == expected, (path, oct(path.stat().st_mode))


def test_fifos_and_devices_given_as_input_are_refused_at_once(tmp_path: Path) -> None:
    """Opening a FIFO waits for a writer and a device never ends: every reader refuses both in
    one line before reading (the batch would run past its timeout otherwise)."""
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    cases = {
        "info": ["info", fifo],
        "convert": ["convert", fifo, "--out", tmp_path / "a.mcap"],
        "convert --from npz": ["convert", "/dev/zero", "--from", "npz", "--out", tmp_path / "b.mcap"],
        "convert --from ros1": ["convert", fifo, "--from", "ros1", "--map", fifo, "--out", tmp_path / "c.mcap"],
        "train bc": ["train", "bc", "--demos", fifo, "--out", tmp_path / "bc"],
        "sweep": ["sweep", fifo, "--out", tmp_path / "sweep"],
        "record sb3": ["record", "--env", "CartPole-v1", "--expert", f"sb3:{fifo}", "--out", tmp_path / "r.mcap"],
    }
    results = run_cli_many(list(cases.values()), timeout=120)
    for (name, argv), result in zip(cases.items(), results):
        device = "/dev/zero" in argv
        expected = "/dev/zero: is a character device" if device else f"{fifo}: is a FIFO"
        assert result.returncode == 1 and result.stderr.strip() == f"error: {expected}, not a regular file; give a file", (name, result.stderr)
    assert not [path for path in tmp_path.iterdir() if path.name != "fifo"]
