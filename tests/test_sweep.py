"""`imitation sweep` with Ray Tune (issue 23): the example sweep (BC's learning rate and width on
CartPole, 8 trials, ASHA) finishes with its table and best run; Ctrl-C and the same command again
continue it without running a finished trial twice; mistakes in the config are one line before
Ray starts; and the training loop's row hook the trials report through."""

from __future__ import annotations

import csv
import importlib.util
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import pytest
import yaml
from support import REPO, run_cli, run_cli_many
from test_cli import assert_one_line_error, last_json

import cli
from imitation.errors import ImitationError
from imitation.jobs.loop import observe_rows
from imitation.jobs.loop import run as run_learner
from imitation.jobs.sweep_config import CommandLine, read_sweep_config
from imitation.jobs.sweep_results import run_result
from imitation.runs import read_run

EXAMPLE = REPO / "docs" / "sweeps" / "bc-cartpole.yaml"
EPOCHS = yaml.safe_load(EXAMPLE.read_text())["args"]["epochs"]
ENDED = re.compile(r"^\[sweep\] trial \d+/8 (\S+) ")
needs_tune = pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="the optional extra ray is not installed")


def sweep_argv(out: Path, *extra: str, config: Path = EXAMPLE) -> list[str]:
    # Two CPUs: the machine's, which the trials share one each.
    return ["sweep", str(config), "--out", str(out), "--cpus", "2", *extra]


def table(out: Path) -> list[dict[str, str]]:
    with open(out / "results.csv", newline="") as stream:
        return list(csv.DictReader(stream))


def ended(stderr: str) -> list[str]:
    """The trials the sweep's progress lines say ended."""
    return [match[1] for line in stderr.splitlines() if (match := ENDED.match(line))]


@needs_tune
def test_the_example_sweep_writes_its_table_and_copies_the_best_run(tmp_path: Path) -> None:
    out = tmp_path / "sweep"
    result = run_cli(*sweep_argv(out, "--json"), timeout=300)
    summary = last_json(result)
    # Ray's own reporting is quiet: stderr holds the sweep's line per trial and nothing else.
    assert len(ended(result.stderr)) == 8 and len(result.stderr.strip().splitlines()) == 8, result.stderr
    rows = table(out)
    assert [row["trial"] for row in rows] == sorted(ended(result.stderr))
    assert summary["trials"] == 8 and summary["finished"] + summary["stopped_early"] == 8 and summary["failed"] == 0
    for row in rows:
        assert row["status"] in ("finished", "stopped early") and float(row["validation_loss"]) > 0
        assert 1 <= int(row["steps"]) <= EPOCHS and row["lr"] and row["hidden"] in ("8", "32,32", "128,128")
        if row["status"] == "finished":
            assert (out / row["run"] / "model.safetensors").is_file()
        else:  # ASHA stopped it at a rung: no finished run directory
            assert not row["run"] and int(row["steps"]) < EPOCHS
    finished = [row for row in rows if row["status"] == "finished"]
    best = min(finished, key=lambda row: float(row["validation_loss"]))
    assert summary["best"]["trial"] == best["trial"]
    config, weights = read_run(out / "best")  # a copy of the best run: loadable as any run directory
    assert config["kind"] == "bc" and weights
    assert (out / "best" / "model.safetensors").read_bytes() == (out / best["run"] / "model.safetensors").read_bytes()
    value, _ = run_result(out / "best", command="train bc", metric="validation_loss", mode="min", scope="best")
    assert value == pytest.approx(float(best["validation_loss"]))
    assert f"{best['trial']} (best)" in (out / "results.md").read_text()


@needs_tune
def test_an_interrupted_sweep_continues_without_running_finished_trials_again(tmp_path: Path) -> None:
    out = tmp_path / "sweep"
    # Without ASHA every trial ends with a finished run directory, whose files must stay as they
    # are; shorter trials, as the test only needs some to end before Ctrl-C and some after.
    args = yaml.safe_load(EXAMPLE.read_text())["args"] | {"epochs": 4}
    config = write_config(tmp_path, "no-asha", scheduler="none", args=args)
    # Ctrl-C in a terminal: SIGINT to the whole process group, Ray's processes included.
    process = subprocess.Popen(
        [sys.executable, str(REPO / "cli.py"), *sweep_argv(out, config=config)],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    assert process.stderr is not None
    lines = []
    for line in process.stderr:
        lines.append(line)
        if len(ended("".join(lines))) == 2:
            os.killpg(process.pid, signal.SIGINT)
            break
    _, rest = process.communicate(timeout=120)
    first = ended("".join(lines) + rest)
    assert process.returncode == 130, rest
    assert "interrupted: the sweep stopped with" in rest and "run the same command again to continue it" in rest
    # A trial may have finished its run directory just before Tune recorded it: the table counts
    # it (from its run directory), and the rerun reports it without running it again.
    assert len(first) <= sum(row["status"] != "not finished" for row in table(out)) < 8
    kept = {
        run: ((run / "metrics.json").stat().st_mtime_ns, (run / "model.safetensors").read_bytes())
        for run in (out / "runs").iterdir()
        if (run / "metrics.json").is_file()
    }
    assert len(kept) >= len(first)
    # Trials stopped in the middle keep their run's last checkpoint, which the rerun continues from.
    partials = [folder for folder in (out / "runs").glob("*.partial") if (folder / "checkpoint").is_dir()]
    continued = [folder.with_name(folder.name.removesuffix(".partial")) for folder in partials]

    # Ray Tune's own state restores by unpickling: planted where Tune kept it, it must not run.
    marker = plant_tune_state(out / "tune")
    second = run_cli(*sweep_argv(out, config=config), timeout=300)
    assert second.returncode == 0, second.stderr
    assert not marker.exists()
    again = ended(second.stderr)
    assert not set(first) & set(again) and len(first) + len(again) == 8
    # The trials run again under their own names: no interrupted trial's folder is left behind.
    assert sorted(first + again) == [f"trial-{index:03d}" for index in range(8)]
    assert not list((out / "runs").glob("*.partial"))
    for run, (mtime, weights) in kept.items():
        assert (run / "metrics.json").stat().st_mtime_ns == mtime and (run / "model.safetensors").read_bytes() == weights
    rows = table(out)
    assert len(rows) == 8 and all(row["status"] == "finished" for row in rows)
    assert (out / "best" / "model.safetensors").is_file()
    for run in continued:  # continued from its checkpoint: the second process added its own events
        assert len(list((run / "tb").iterdir())) == 2


def descendant(pid: int, name: str, timeout: float = 120) -> int:
    """The first process below `pid` whose command line holds `name`, once one runs."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        children = {pid}
        for _ in range(6):  # Ray's processes sit a few generations below the sweep
            for entry in Path("/proc").iterdir():
                try:
                    parent = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
                    command = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
                except (OSError, ValueError, IndexError):
                    continue
                if parent in children:
                    if name in command:
                        return int(entry.name)
                    children.add(int(entry.name))
        time.sleep(0.2)
    raise AssertionError(f"no process {name!r} below {pid} within {timeout} s")


@needs_tune
def test_a_sweep_outlives_ray_and_says_what_became_of_its_trials(tmp_path: Path) -> None:
    """A trial whose Ray worker is killed fails in a short line; Ray's node killed under the sweep
    (its dashboard agent, which Ray's raylet shares its fate with, and the driver with that)
    ends the sweep with one line and the table, rather than exit 1 with neither."""
    args = yaml.safe_load(EXAMPLE.read_text())["args"] | {"epochs": 400, "patience": 400}
    config = write_config(tmp_path, "long", args=args, trials=3, scheduler="none")
    out = tmp_path / "sweep"
    process = subprocess.Popen([sys.executable, str(REPO / "cli.py"), *sweep_argv(out, config=config)], cwd=REPO,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        os.kill(descendant(process.pid, "ray::ImplicitFunc"), signal.SIGKILL)  # a trial's worker
        assert process.stderr is not None
        failed = process.stderr.readline()
        os.kill(descendant(process.pid, "ray::DashboardAgent"), signal.SIGKILL)
        _, rest = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            process.kill()
    assert failed.startswith("[sweep] trial 1/3 ") and failed.endswith(" failed: its Ray worker process died (killed, or out of memory)\n")
    *_, last = rest.strip().splitlines()
    assert process.returncode == 1 and last.startswith("error: Ray stopped in the middle of the sweep (its process ended with "), rest
    assert f"trials ended (table: {out / 'results.md'}); run the same command again to continue the sweep" in last
    rows = table(out)
    assert len(rows) == 3 and "error: its Ray worker process died (killed, or out of memory)" in [row["status"] for row in rows]
    assert "not finished" in [row["status"] for row in rows] and (out / "ray.log").stat().st_size > 0


def test_semaphores_a_killed_tune_leaves_are_reported_in_the_ray_log_not_after_the_error(tmp_path: Path) -> None:
    """multiprocessing's resource tracker outlives the sweep and warns of the semaphores a Tune
    child ended by Ray left behind: that warning goes to ray.log, where it cannot follow the
    sweep's one-line error (a CI run once ended with it as stderr's last line)."""
    log = tmp_path / "ray.log"
    leaks = (
        "import multiprocessing, os, pathlib\n"
        "from imitation.jobs.sweep_process import _track_resources_into\n"
        f"_track_resources_into(pathlib.Path({str(log)!r}))\n"
        "lock = multiprocessing.get_context('spawn').Lock()\n"
        "os._exit(0)\n"
    )
    result = subprocess.run([sys.executable, "-c", leaks], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert result.returncode == 0 and result.stderr == ""
    deadline = time.monotonic() + 30  # the tracker writes once it sees the process gone
    while "leaked semaphore" not in log.read_text() and time.monotonic() < deadline:
        time.sleep(0.1)
    assert "leaked semaphore" in log.read_text()


def plant_tune_state(folder: Path) -> Path:
    """Ray Tune's experiment state as a continued sweep once restored it, each file carrying a
    pickle that creates the returned marker file when unpickled: `tuner.pkl`, and an
    `experiment_state-*.json` whose trial holds one as Tune's cloudpickle fallback."""
    import pickle

    marker = folder.parent / "code-ran"

    class Payload:
        def __reduce__(self) -> tuple:
            return (exec, (f"open({str(marker)!r}, 'w').write('ran')",))

    folder.mkdir(parents=True, exist_ok=True)
    (folder / "tuner.pkl").write_bytes(pickle.dumps(Payload()))
    fallback = {"_type": "CLOUDPICKLE_FALLBACK", "value": pickle.dumps(Payload()).hex()}
    state = {"trial_data": [[json.dumps({"config": fallback}), json.dumps({"status": "RUNNING"})]], "runner_data": {}}
    (folder / "experiment_state-2026-12-06_00-00-00.json").write_text(json.dumps(state))
    return marker


@needs_tune
def test_a_sweep_whose_every_trial_fails_says_why_in_one_line(tmp_path: Path) -> None:
    """Run from a folder holding a cli.py and an imitation/ package of its own, which Ray's
    workers must not import; Optuna names the trials."""
    args = yaml.safe_load(EXAMPLE.read_text())["args"] | {"epochs": 2, "demos": str(REPO / "datasets" / "CartPole-v1.mcap")}
    config = write_config(tmp_path, "typo", args=args, trials=2, scheduler="none", metric="val_loss", mode="min", search="optuna")
    here = tmp_path / "here"
    (here / "imitation").mkdir(parents=True)
    marker = tmp_path / "code-ran"
    planted = f"open({str(marker)!r}, 'a').write(__name__)\n"
    for module in (here / "cli.py", here / "imitation" / "__init__.py"):
        module.write_text(planted)
    result = run_cli(*sweep_argv(tmp_path / "sweep", config=config), timeout=300, cwd=here)
    assert not marker.exists(), marker.read_text()
    message = "train bc logs no column 'val_loss'; its rows have epoch, train_loss, validation_loss"
    *progress, last = result.stderr.strip().splitlines()
    assert (
        result.returncode == 1 and last.startswith("error: every trial of the sweep failed, the first (") and message in last
    )
    assert len(progress) == 2 and all(line.startswith("[sweep] trial ") and f"failed: {message}" in line for line in progress)
    rows = table(tmp_path / "sweep")
    assert len(rows) == 2 and all(row["status"].startswith(f"error: {message}") for row in rows)


def write_config(folder: Path, name: str, **changes: object) -> Path:
    """The example with `changes` (None removes a key), as `name`.yaml."""
    document = yaml.safe_load(EXAMPLE.read_text())
    for key, value in changes.items():
        if value is None:
            document.pop(key)
        else:
            document[key] = value
    path = folder / f"{name}.yaml"
    path.write_text(yaml.safe_dump(document))
    return path


def test_config_mistakes_are_one_line_naming_the_file_and_key_before_ray_starts(tmp_path: Path) -> None:
    args = yaml.safe_load(EXAMPLE.read_text())["args"]
    cases = {
        "unknown-key": ({"trails": 8}, "unknown key 'trails' (did you mean 'trials'?)"),
        "unknown-flag": ({"args": args | {"learning-rate": 0.1}}, "args.learning-rate: not a flag of this command"),
        "swept-unknown-flag": ({"space": {"width": {"choice": ["8"]}}}, "space.width: not a flag of this command"),
        "sweep-sets-it": ({"args": args | {"out": "x"}}, "args.out: set by the sweep"),
        "bad-distribution": ({"space": {"lr": {"lognormal": [0.1, 1]}}}, "space.lr: a distribution: one of"),
        "bad-range": ({"space": {"lr": {"loguniform": [0, 0.1]}}}, "space.lr: loguniform needs 0 < low, got 0.0"),
        "empty-range": ({"space": {"lr": {"uniform": [0.1, 0.01]}}}, "space.lr: uniform needs low < high"),
        "bad-value": ({"space": {"batch-size": {"choice": [64, "big"]}}}, "space.batch-size: 'big': argument --batch-size"),
        "twice": ({"space": {"epochs": {"choice": [5, 10]}}}, "space.epochs: the flag is also in args"),
        "bad-fixed": ({"args": args | {"epochs": "ten"}}, "fails: argument --epochs: invalid int value: 'ten'"),
        "bad-command": ({"command": "train bcc"}, "command: 'train bcc' is not a train command (did you mean 'train bc'?)"),
        "grid-optuna": ({"search": "optuna", "space": {"lr": {"grid": [0.1, 0.01]}}}, "space.lr: grid needs search: random"),
        "no-mode": ({"metric": "train_loss", "mode": None}, "mode: missing: say whether a lower (min) or higher (max)"),
        "bad-asha": ({"scheduler": {"asha": {"grace": 2}}}, "scheduler.asha.grace: unknown"),
        "bad-trials": ({"trials": 0}, "trials: must be at least 1, got 0"),
        "huge-seed": ({"seed": 2**70}, f"seed: must be a whole number from 0 to 4294967295, got {2**70}"),
        "empty-space": ({"space": {}}, "space: give at least one flag to search over"),
    }
    paths = {name: write_config(tmp_path, name, **changes) for name, (changes, _) in cases.items()}
    results = run_cli_many([["sweep", str(paths[name]), "--out", str(tmp_path / f"out-{name}")] for name in cases])
    for (name, (_, fragment)), result in zip(cases.items(), results):
        assert_one_line_error(result, f"error: {paths[name]}: ", fragment)
        assert not (tmp_path / f"out-{name}").exists()


@needs_tune
def test_a_sweep_keeps_to_its_own_folder(tmp_path: Path) -> None:
    listed = tmp_path / "list.yaml"
    listed.write_text("- command\n")
    stranger, other, torn = tmp_path / "stranger", tmp_path / "other", tmp_path / "torn"
    stranger.mkdir()
    (stranger / "notes.txt").write_text("mine")
    other.mkdir()
    settings = read_sweep_config(EXAMPLE, cli._command_line()).to_json()
    (other / "sweep.json").write_text(json.dumps(settings | {"seed": 1}))
    torn.mkdir()
    (torn / "sweep.json").write_text("{")
    # A sweep's record of its trials, edited to run a trial with a value outside the space; and
    # a sweep of an earlier version, which left only Tune's state to continue from.
    edited, older = tmp_path / "edited", tmp_path / "older"
    for folder in (edited, older):
        (folder / "runs" / "a1b2c3_00000").mkdir(parents=True)
        (folder / "sweep.json").write_text(json.dumps(settings))
    record = {"trial": "trial-000", "params": {"lr": "0.1 --demos /etc/passwd", "hidden": "8"}, "status": "not finished"}
    (edited / "trials.json").write_text(json.dumps({"trials": [record]}))
    results = run_cli_many(
        [
            ["sweep", str(listed), "--out", str(tmp_path / "out")],
            ["sweep", str(EXAMPLE), "--out", str(stranger)],
            ["sweep", str(EXAMPLE), "--out", str(other)],
            ["sweep", str(EXAMPLE), "--out", str(torn)],
            ["sweep", str(EXAMPLE), "--out", str(edited)],
            ["sweep", str(EXAMPLE), "--out", str(older)],
        ]
    )
    assert_one_line_error(results[0], f"{listed}: a sweep config is a YAML mapping (command, args, space, ...), not a list")
    assert_one_line_error(results[1], f"{stranger}: not empty and not a sweep's folder (no sweep.json)")
    assert_one_line_error(results[2], f"{other}: holds a sweep with other settings (seed differs from {EXAMPLE}'s)")
    assert_one_line_error(results[3], f"{torn / 'sweep.json'}: unreadable (")
    assert_one_line_error(
        results[4], f"{edited / 'trials.json'}: unreadable (trial trial-000: lr '0.1 --demos /etc/passwd' is outside the sweep's space)"
    )
    assert_one_line_error(results[5], f"{older}: holds a sweep without trials.json (one from an earlier version")
    assert (stranger / "notes.txt").read_text() == "mine" and sorted(path.name for path in other.iterdir()) == ["sweep.json"]


def test_random_search_plans_every_trial_from_the_seed_within_the_space() -> None:
    from imitation.jobs.sweep_trials import plan_trials

    config = read_sweep_config(write_config(Path(tempfile.mkdtemp()), "grid", space={
        "lr": {"loguniform": [1.0e-4, 1.0e-1]}, "batch-size": {"randint": [16, 18]}, "hidden": {"grid": ["8", "16"]}}, trials=50),
        cli._command_line())
    planned = plan_trials(config)
    assert [trial.trial for trial in planned] == [f"trial-{index:03d}" for index in range(100)]
    assert [trial.params["hidden"] for trial in planned] == ["8", "16"] * 50  # each sample runs the whole grid
    assert {trial.params["batch-size"] for trial in planned} == {16, 17, 18}  # randint includes both ends
    rates = [trial.params["lr"] for trial in planned]
    assert all(1.0e-4 <= rate <= 1.0e-1 for rate in rates) and min(rates) < 1e-3 < max(rates) and len(set(rates)) == 100
    assert [trial.params for trial in plan_trials(config)] == [trial.params for trial in planned]


def test_neither_help_nor_a_refused_config_imports_ray(tmp_path: Path) -> None:
    bad = write_config(tmp_path, "bad", trails=8)
    script = (
        "import contextlib, io, sys, cli\n"
        "with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):\n"
        "    code = cli.main(['sweep', sys.argv[1], '--out', sys.argv[2]])\n"
        "    try:\n        cli.main(['sweep', '--help'])\n    except SystemExit:\n        pass\n"
        "print(code, any(name == 'ray' or name.startswith('ray.') for name in sys.modules))\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", script, str(bad), str(tmp_path / "out")], capture_output=True, text=True, cwd=REPO, timeout=60
    )
    assert result.stdout.split() == ["1", "False"], result.stderr


@dataclass
class Counter:
    """A learner of `total` steps whose rows count them; `inner` runs inside each step."""

    total: int
    inner: Counter | None = None
    name: str = "counter"
    unit: str = "step"
    steps: int = 0

    @property
    def completed(self) -> int:
        return self.steps

    @property
    def done(self) -> bool:
        return self.steps >= self.total

    def position(self) -> str:
        return f"step {self.steps}"

    def progress(self, row: dict[str, float]) -> dict[str, str]:
        return {}

    def step(self) -> dict[str, float]:
        if self.inner is not None:
            self.inner.steps = 0
            run_learner(self.inner)
        self.steps += 1
        return {"step": float(self.steps)}

    def state_dict(self) -> tuple[dict, dict]:
        return {}, {}

    def load_state_dict(self, checkpoint: tuple[dict, dict]) -> None:
        pass


def test_observe_rows_sees_each_row_of_the_outermost_run_only() -> None:
    seen: list[tuple[str, int, float]] = []
    outer = Counter(total=3, inner=Counter(total=2, name="inner"))
    with observe_rows(lambda learner, row: seen.append((learner.name, learner.completed, row["step"]))):
        rows = run_learner(outer)
    assert seen == [("counter", 1, 1.0), ("counter", 2, 2.0), ("counter", 3, 3.0)] and len(rows) == 3
    run_learner(Counter(total=2))  # outside the block: nobody is told
    assert len(seen) == 3


@needs_tune
def test_a_trial_fails_at_its_first_row_without_the_metric_and_reports_finite_figures() -> None:
    from imitation.jobs.sweep_tune import STEPS, reporter

    reports: list[dict[str, float]] = []
    observe = reporter("validation_loss", "train bc", reports.append)
    learner = Counter(total=1, steps=4)
    observe(learner, {"validation_loss": float("nan"), "return": 1.0})  # no figure to judge: not reported
    observe(learner, {"validation_loss": 0.5, "return": float("nan")})
    assert reports == [{"validation_loss": 0.5, STEPS: 4}]
    with pytest.raises(ImitationError, match=r"train bc logs no column 'validation_loss'; its rows have return"):
        observe(learner, {"return": 1.0})


def test_a_run_without_a_finite_metric_has_no_result(tmp_path: Path) -> None:
    (tmp_path / "progress.csv").write_text("epoch,validation_loss,return\n1,0.5,nan\n2,0.4,nan\n")
    assert run_result(tmp_path, command="train bc", metric="validation_loss", mode="min", scope="best") == (0.4, 2)
    assert run_result(tmp_path, command="train bc", metric="validation_loss", mode="min", scope="last") == (0.4, 2)
    with pytest.raises(ImitationError, match=r"train bc: no finite return in any of the 2 rows of "):
        run_result(tmp_path, command="train bc", metric="return", mode="max", scope="last")
