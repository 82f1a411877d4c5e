"""The MuJoCo table (issue 20): normalised returns of BC, DAgger, GAIL, AIRL, PPO retrained on AIRL's
and GCL's recovered rewards (and on AIRL's g shaped by its h, `airl-shaped-ppo`), on the fixed-horizon
locomotion tasks (`imitation/…FixedHorizon-v0`: gymnasium v5, no termination, 1000 steps), beside
HumanCompatibleAI/imitation's published figures and, with `--peer`, imitation 1.0.1 itself run here on the
same demos (BC and GAIL; bench/mujoco_peer.py).

(Not bench/mujoco.py: a script's own folder comes first on sys.path, where that name would shadow the
mujoco package gymnasium imports.)

Every run is the command a user would type (`imitation record`, `train bc`, `train dagger`, `train irl`,
`train ppo --reward`), in a fresh process, its wall time measured. Each finished run is appended to
OUT/results.jsonl, so an interrupted benchmark resumes where it stopped.

- Experts: rl-baselines3-zoo's SAC agents for HalfCheetah-v3 and Hopper-v3 (../shared/testdata,
  `--expert sb3:ZIP`), acting on v5, whose observations are laid out as v3's; an expert given with
  `--expert ENV=SPEC` (a run directory of `train ppo`, or `sb3:ZIP`); or, with `--ppo-expert ENV`, one
  trained here on the task's own reward (`train ppo --steps 1000000 --seed 0` into OUT/ENV-ppo-expert,
  once). The zoo's Hopper falls after ~300 steps on v5 (bench/RESULTS.md), our PPO's hops on.
- Demos: `--episodes` (default 25) expert episodes per task, recorded with seeds from 1000 and DART
  noise (`record --action-noise`, default 0.1: with that probability a step executes a random
  action while the file keeps the expert's), so that the demos show the states just off the expert's
  path, labelled. Every learner, ours and the peer's, gets the same file. `--action-noise ENV=0`
  records one task's demos clean: GAIL and AIRL match the states the demos visit, so noise that
  knocks the expert over (our PPO's HalfCheetah gait) becomes part of what they imitate.
- `--airl-restart [ENV=]N`: PPO from scratch retrains on the g of a second AIRL run (N steps) whose
  discriminator starts from the AIRL row's run and whose policy starts afresh, so that g also gets
  fitted against a policy that has not learnt to run yet (`train irl --warm-start`); the AIRL row
  stays the first run's policy.
- Normalised return = (R − R_random) / (R_expert − R_random): R the policy's mean over the 10
  deterministic evaluation episodes every `train` command ends with, R_expert the expert's own mean
  over 10 noise-free episodes (recorded with seeds from 2000), R_random a uniform random policy's
  mean over 10 episodes (seeds 0-9).

With `--workers N` our runs go to Ray as tasks, N at a time (`--ray-address`: a cluster whose
nodes see this checkout and OUT at the same paths; "local" by default), each finished run recorded as
it returns; the runs of PPO on a recovered reward go after the IRL runs whose rewards they reuse.

Usage: python bench/mujoco_table.py [--envs HalfCheetah,Hopper]
       [--methods bc,dagger,gail,airl,airl-ppo,airl-shaped-ppo,gcl-ppo] [--seeds 0,1,2] [--irl-steps N]
       [--retrain-steps N] [--gail-args FLAGS] [--airl-args FLAGS] [--airl-restart [ENV=]N]
       [--expert ENV=SPEC | --ppo-expert ENV] [--action-noise [ENV=]P]
       [--peer] [--out bench/mujoco-runs]
       [--workers N [--ray-address ADDR]]
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

BENCH = Path(__file__).resolve().parent
ROOT = BENCH.parent
ZOO = ROOT.parent / "shared" / "testdata" / "experts" / "zoo"
# The peer's gymnasium 0.29 runs the v4 tasks on the same MuJoCo as ours (imageio: gymnasium's mujoco extra).
PEER_MUJOCO = ["mujoco==4.0.1", "imageio"]
METHODS = ("bc", "dagger", "gail", "airl", "airl-ppo", "airl-shaped-ppo", "gcl-ppo")
# HumanCompatibleAI/imitation's published aggregate over its seals MuJoCo tasks (its README's
# benchmark summary; quoted in issue 20): normalised between a random policy and the expert.
PUBLISHED = {"bc": 0.93, "dagger": 0.995, "gail": 0.94, "airl": 0.79}


def zoo_expert(env: str) -> str | None:
    path = ZOO / f"sac_{env}-v3" / f"{env}-v3.zip"
    return f"sb3:{path}" if path.exists() else None


def train_ppo_expert(env_id: str, run: Path, args: argparse.Namespace) -> None:
    """RUN, a run directory of `train ppo` on the task's reward, unless it exists (1M steps, seed 0)."""
    if not run.exists():
        result, seconds = cli(
            "train", "ppo", "--env", env_id, "--steps", "1000000", "--seed", "0", "--out", str(run), threads=args.threads
        )
        print(f"{env_id}: PPO expert {result['eval']['mean_return']:.1f} in {seconds:.0f} s", flush=True)


def cli(*args: str, threads: int) -> tuple[dict[str, Any], float]:
    """`imitation ARGS --json --quiet` in a fresh process: its JSON result and wall seconds."""
    env = dict(os.environ, OMP_NUM_THREADS=str(threads), MKL_NUM_THREADS=str(threads), MUJOCO_GL="egl")
    started = time.perf_counter()
    completed = subprocess.run(
        [sys.executable, str(ROOT / "cli.py"), *args, "--json", "--quiet"], capture_output=True, text=True, cwd=ROOT, env=env
    )
    seconds = time.perf_counter() - started
    if completed.returncode != 0:
        raise RuntimeError(f"imitation {' '.join(args)} failed: {completed.stderr.strip()[-2000:]}")
    return json.loads(completed.stdout.strip().splitlines()[-1]), seconds


def random_return(env_id: str) -> float:
    import imitation.envs  # noqa: F401  (registers the ids)
    from imitation.envs.make import make_env
    from imitation.evaluation.policy import evaluate_policy

    env = make_env(env_id)
    env.action_space.seed(0)
    return evaluate_policy(lambda observation: env.action_space.sample(), env, episodes=10, seed=0)["mean_return"]


def irl_steps(args: argparse.Namespace) -> list[str]:
    """`--steps N` for our IRL runs when --irl-steps is given; else none, for the task's preset."""
    return ["--steps", str(args.irl_steps)] if args.irl_steps else []


def peer_irl_steps(env: str, args: argparse.Namespace) -> int:
    """The peer's GAIL budget: the same as ours."""
    from imitation.jobs.presets import preset

    return args.irl_steps or preset(f"imitation/{env}FixedHorizon-v0").irl_steps


def demo_return(path: Path) -> float:
    from imitation.data.dataset import DemoDataset

    return float(np.mean([facts.episode_return for facts in DemoDataset([path]).episodes]))


def per_task(convert: Callable[[str], Any], what: str) -> Callable[[str], tuple[str, Any]]:
    """An argparse type for [ENV=]VALUE: (ENV or '' for every task, convert(VALUE))."""

    def parse(text: str) -> tuple[str, Any]:
        env, _, value = text.rpartition("=")
        try:
            return env, convert(value)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{value!r} is not {what}") from None

    return parse


def recorded_noise(demos: Path) -> float:
    """The DART noise a demo file was recorded with (`record` writes none when there was none)."""
    from imitation.data.mcap.reader import DemoFile

    return float(DemoFile(demos).user_metadata.get("action_noise", 0.0))


def export_npz(demos: Path, out: Path) -> Path:
    """The demos as the peer reads them: obs, acts, next_obs (float32) and dones (episode ends),
    written under a temporary name and renamed, for the seeds' processes run side by side."""
    from imitation.data.dataset import DemoDataset
    from imitation.data.loader import load_transitions

    transitions = load_transitions(DemoDataset([demos]), next_observations=True)
    partial = out.with_name(f"{out.stem}.{os.getpid()}.partial.npz")
    np.savez(
        partial,
        obs=np.asarray(transitions.observations, dtype=np.float32),
        acts=np.asarray(transitions.actions, dtype=np.float32),
        next_obs=np.asarray(transitions.next_observations, dtype=np.float32),
        dones=transitions.dones,
    )
    partial.replace(out)
    return out


def ensure_peer() -> tuple[Path | None, str]:
    """bench/.venv-imitation (bench/bc.py makes it) with MuJoCo added; (None, why) if impossible."""
    import bc  # bench/bc.py, beside this script: it makes the peer venv

    python, versions = bc.ensure_imitation_venv()
    if python is None:
        return None, versions
    probe = [str(python), "-c", "import mujoco, imageio"]
    if subprocess.run(probe, capture_output=True, cwd=BENCH, env=bc._peer_env()).returncode != 0:
        install = [str(python), "-m", "pip", "install", "--quiet", "--disable-pip-version-check", *PEER_MUJOCO]
        completed = subprocess.run(install, capture_output=True, text=True)
        if completed.returncode != 0:
            return None, f"`{' '.join(install)}` failed: {completed.stderr.strip()[-1000:]}"
    return python, f"{versions}, {' '.join(PEER_MUJOCO)}"


def run_peer(python: Path, spec: dict[str, Any]) -> tuple[dict[str, Any], float]:
    """One run of bench/mujoco_peer.py in the peer venv: its result and wall seconds."""
    import bc  # bench/bc.py, beside this script

    with tempfile.TemporaryDirectory(prefix="bench-mujoco-") as workdir:
        spec_path, result_path = Path(workdir) / "spec.json", Path(workdir) / "result.json"
        spec_path.write_text(json.dumps(spec))
        started = time.perf_counter()
        completed = subprocess.run(
            [str(python), str(BENCH / "mujoco_peer.py"), str(spec_path), str(result_path)],
            capture_output=True, text=True, cwd=BENCH, env=bc._peer_env(),
        )  # fmt: skip
        seconds = time.perf_counter() - started
        if completed.returncode != 0:
            raise RuntimeError(f"mujoco_peer.py {spec} failed: {completed.stderr.strip()[-2000:]}")
        return json.loads(result_path.read_text()), seconds


class Results:
    """OUT/results.jsonl: one line per finished run, keyed by (side, env, method, seed)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.rows = [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []

    def get(self, side: str, env: str, method: str, seed: int) -> dict[str, Any] | None:
        return next((r for r in self.rows if (r["side"], r["env"], r["method"], r["seed"]) == (side, env, method, seed)), None)

    def add(self, row: dict[str, Any]) -> None:
        self.rows.append(row)
        with self.path.open("a") as file:
            file.write(json.dumps(row) + "\n")


def our_run(
    method: str, env_id: str, expert: str, demos: Path, seed: int, runs: Path, args: argparse.Namespace
) -> tuple[float, float]:
    """One of our runs: (the policy's mean return, wall seconds, retraining included)."""
    common = ["--env", env_id, "--seed", str(seed)]
    irl_flags = {"gail": shlex.split(args.gail_args), "airl": shlex.split(args.airl_args)}
    out = runs / f"{method}-{seed}"
    if method == "bc":
        result, seconds = cli("train", "bc", *common, "--demos", str(demos), "--out", str(out), threads=args.threads)
    elif method == "dagger":
        result, seconds = cli(
            "train", "dagger", *common, "--expert", expert, "--demos", str(demos), "--rounds", str(args.dagger_rounds),
            "--out", str(out), threads=args.threads,
        )  # fmt: skip
    elif method in ("gail", "airl"):
        result, seconds = cli(
            "train", "irl", "--method", method, *common, "--demos", str(demos), *irl_steps(args),
            *irl_flags[method], "--out", str(out), threads=args.threads,
        )  # fmt: skip
    else:
        irl = method.removesuffix("-ppo").removesuffix("-shaped")
        shaped = ["--shaped"] if method == "airl-shaped-ppo" else []
        reward = runs / f"{irl}-reward-{seed}"
        if irl == "airl" and (runs / f"airl-{seed}").exists():
            reward, seconds = runs / f"airl-{seed}", 0.0  # the AIRL row's run: its g
        else:
            _, seconds = cli(
                "train", "irl", "--method", irl, *common, "--demos", str(demos), *irl_steps(args),
                *irl_flags.get(irl, []), "--out", str(reward), threads=args.threads,
            )  # fmt: skip
        restart = args.airl_restart.get(runs.name, args.airl_restart.get("", 0))  # runs: OUT/ENV
        if irl == "airl" and restart:
            restarted = runs / f"airl-restart-{seed}"
            if not restarted.exists():
                _, more = cli(
                    "train", "irl", "--method", "airl", *common, "--demos", str(demos), "--steps", str(restart),
                    *irl_flags["airl"], "--warm-start", str(reward), "--out", str(restarted), threads=args.threads,
                )  # fmt: skip
                seconds += more
            reward = restarted
        result, retrain = cli(
            "train", "ppo", *common, "--reward", str(reward), *shaped, "--steps", str(args.retrain_steps), "--out", str(out),
            threads=args.threads,
        )  # fmt: skip
        seconds += retrain
    return float(result["eval"]["mean_return"]), seconds


Cell = tuple[str, str, str, int]  # (env, method, env id, seed)


def our_runs(
    cells: list[Cell], experts: dict[str, str], demos: dict[str, Path], args: argparse.Namespace
) -> Iterator[tuple[Cell, float, float]]:
    """(cell, return, seconds) of each of our runs, as they finish: one after another, or as Ray
    tasks (`--workers`), the reward-retraining runs after the IRL runs they reuse."""

    def run(cell: Cell) -> tuple[float, float]:
        env, method, env_id, seed = cell
        return our_run(method, env_id, experts[env], demos[env], seed, args.out / env, args)

    if args.workers is None:
        for cell in cells:
            yield (cell, *run(cell))
        return
    sys.path.insert(0, str(ROOT))
    from imitation.ray_engine import RETRIES, ray_get, ray_session

    with ray_session(args.ray_address, num_cpus=args.workers * args.threads) as ray:
        task = ray.remote(num_cpus=args.threads, max_retries=RETRIES)(run)
        for phase in (False, True):  # IRL and imitation runs, then PPO on the rewards they recovered
            pending = {task.remote(cell): cell for cell in cells if cell[1].endswith("-ppo") == phase}
            while pending:
                [done], _ = ray.wait(list(pending))
                yield (pending.pop(done), *ray_get(ray, done))


def table(results: Results, envs: list[str], methods: list[str], scale: dict[str, tuple[float, float]]) -> str:
    """Markdown: per task and method, our mean normalised return with the seeds' figures and the
    mean wall time; the peer's measured mean and imitation's published aggregate beside it."""
    lines = [
        "| task | method | ours: mean (seeds) | wall time / run | imitation 1.0.1 here: mean (seeds) "
        "| imitation published (aggregate) |",
        "|---|---|---|---|---|---|",
    ]
    for env in envs:
        random, expert = scale[env]
        for method in methods:
            cells = []
            for side in ("ours", "peer"):
                rows = [r for r in results.rows if (r["side"], r["env"], r["method"]) == (side, env, method)]
                normalised = [(r["return"] - random) / (expert - random) for r in sorted(rows, key=lambda r: r["seed"])]
                cells.append(
                    (
                        f"{np.mean(normalised):.2f} ({', '.join(f'{n:.2f}' for n in normalised)})",
                        f"{np.mean([r['seconds'] for r in rows]):.0f} s",
                    )
                    if rows
                    else ("–", "–")
                )
            published = f"{PUBLISHED[method]:.3g}" if method in PUBLISHED else "–"
            lines.append(f"| {env} | {method} | {cells[0][0]} | {cells[0][1]} | {cells[1][0]} | {published} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--envs", default="HalfCheetah,Hopper")
    parser.add_argument("--methods", default=",".join(METHODS))
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--episodes", type=int, default=25, help="expert demo episodes per task")
    parser.add_argument(
        "--action-noise",
        action="append",
        default=[],
        type=per_task(float, "a probability"),
        metavar="[ENV=]P",
        help="DART noise of the demos (record --action-noise): P for every task (default 0.1), ENV=P for one",
    )
    parser.add_argument(
        "--irl-steps", type=int, help="PPO steps of every IRL run (default: the task's preset, HalfCheetah 3M, the others 1M)"
    )
    parser.add_argument("--retrain-steps", type=int, default=1_000_000)
    parser.add_argument("--dagger-rounds", type=int, default=5)
    parser.add_argument(
        "--gail-args", default="", metavar="FLAGS", help="more `train irl` flags for our GAIL, e.g. '--gail-reward logit'"
    )
    parser.add_argument(
        "--airl-args",
        default="",
        metavar="FLAGS",
        help=(
            "more `train irl` flags for our AIRL (its own row and the g that airl-ppo retrains on), "
            "e.g. '--pool-rollouts 1000'"
        ),
    )
    parser.add_argument(
        "--airl-restart",
        action="append",
        default=[],
        type=per_task(int, "a number of steps"),
        metavar="[ENV=]N",
        help=(
            "airl-ppo and airl-shaped-ppo retrain on the g of a second AIRL run of N steps (airl-restart-SEED) whose "
            "discriminator starts from the AIRL row's and its policy from scratch (`train irl --warm-start`); ENV=N "
            "for one task (default: none, the AIRL row's own g)"
        ),
    )
    parser.add_argument(
        "--expert", action="append", default=[], metavar="ENV=SPEC", help="an expert for a task without a zoo one"
    )
    parser.add_argument(
        "--ppo-expert", action="append", default=[], metavar="ENV", help="train the task's expert with our PPO (1M steps)"
    )
    parser.add_argument("--peer", action="store_true", help="also run imitation 1.0.1's BC and GAIL on the same demos")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out", type=Path, default=BENCH / "mujoco-runs")
    parser.add_argument("--workers", type=int, metavar="N", help="run ours as Ray tasks, N at a time (default: one by one)")
    parser.add_argument("--ray-address", default="local", metavar="ADDR|auto|local")
    args = parser.parse_args()
    args.out = args.out.resolve()  # the peer runs in bench/, our runs in the checkout: one absolute path for both
    envs, methods, seeds = args.envs.split(","), args.methods.split(","), [int(s) for s in args.seeds.split(",")]
    experts = dict(spec.split("=", 1) for spec in args.expert)
    noises = dict(args.action_noise)
    args.airl_restart = dict(args.airl_restart)
    args.out.mkdir(parents=True, exist_ok=True)
    results = Results(args.out / "results.jsonl")
    peer = ensure_peer() if args.peer else (None, "not asked (--peer)")
    print(f"imitation 1.0.1: {peer[1]}", flush=True)
    scale: dict[str, tuple[float, float]] = {}
    demo_files: dict[str, Path] = {}
    cells: list[Cell] = []
    for env in envs:
        env_id = f"imitation/{env}FixedHorizon-v0"
        ppo_run = args.out / f"{env}-ppo-expert"
        expert = experts.get(env) or (str(ppo_run) if env in args.ppo_expert else zoo_expert(env))
        if expert is None:
            print(f"{env}: no expert (give --expert {env}=SPEC or --ppo-expert {env}); skipped", flush=True)
            continue
        # The demos and every result in OUT belong to one expert: another one needs another --out
        # (checked before an expert is trained for it).
        recorded_by = args.out / f"{env}-expert.txt"
        if recorded_by.exists() and recorded_by.read_text() != expert:
            sys.exit(f"{args.out}: its {env} demos are {recorded_by.read_text()}'s, not {expert}'s; give another --out")
        if expert == str(ppo_run):
            train_ppo_expert(env_id, ppo_run, args)
        if not recorded_by.exists():  # renamed into place: the seeds' processes run side by side read it
            partial = recorded_by.with_name(f"{recorded_by.name}.{os.getpid()}.partial")
            partial.write_text(expert)
            partial.replace(recorded_by)
        demos, clean = args.out / f"{env}-demos.mcap", args.out / f"{env}-expert.mcap"
        recording = ["record", "--env", env_id, "--expert", expert]
        noise = noises.get(env, noises.get("", 0.1))
        recorded = recorded_noise(demos) if demos.exists() else noise
        if recorded != noise:
            sys.exit(f"{demos}: recorded with --action-noise {recorded}, not {noise}; give another --out")
        if not demos.exists():
            cli(
                *recording,
                "--episodes",
                str(args.episodes),
                "--seed",
                "1000",
                "--action-noise",
                str(noise),
                "--out",
                str(demos),
                threads=args.threads,
            )
        if not clean.exists():
            cli(*recording, "--episodes", "10", "--seed", "2000", "--out", str(clean), threads=args.threads)
        scale[env] = (random_return(env_id), demo_return(clean))
        print(f"{env}: random {scale[env][0]:.1f}, expert {scale[env][1]:.1f}, demos {demo_return(demos):.1f}", flush=True)
        experts[env], demo_files[env] = expert, demos
        cells += [(env, m, env_id, seed) for m in methods for seed in seeds if results.get("ours", env, m, seed) is None]
    for (env, method, _, seed), returned, seconds in our_runs(cells, experts, demo_files, args):
        results.add({"side": "ours", "env": env, "method": method, "seed": seed, "return": returned, "seconds": seconds})
        print(f"{env} {method} seed {seed}: ours {returned:.1f} in {seconds:.0f} s", flush=True)
    for env in scale:
        demos = demo_files[env]
        for method in methods:
            for seed in seeds:
                if peer[0] is not None and method in ("bc", "gail") and results.get("peer", env, method, seed) is None:
                    spec = {
                        "method": method, "env": env, "demos": str(export_npz(demos, args.out / f"{env}-demos.npz")),
                        "seed": seed, "eval_episodes": 10, "total_timesteps": peer_irl_steps(env, args),
                    }  # fmt: skip
                    result, seconds = run_peer(peer[0], spec)
                    results.add(
                        {
                            "side": "peer",
                            "env": env,
                            "method": method,
                            "seed": seed,
                            "return": result["mean_return"],
                            "seconds": seconds,
                        }
                    )
                    print(
                        f"{env} {method} seed {seed}: imitation 1.0.1 {result['mean_return']:.1f} in {seconds:.0f} s",
                        flush=True,
                    )
    report = table(results, [e for e in envs if e in scale], methods, scale)
    (args.out / "table.md").write_text(report + "\n")
    print(report)


if __name__ == "__main__":
    main()
