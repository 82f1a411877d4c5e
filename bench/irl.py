"""Benchmark: our tabular MCE IRL vs HumanCompatibleAI/imitation 1.0.1's `MCEIRL`.

Both sides learn a linear reward on one-hot states (theirs: `BasicRewardNet(hid_sizes=[])`, a
linear layer with a bias; ours: `hidden_sizes=[]`, the same) of seals' CliffWorld with one-hot
observations, at the sizes imitation uses (7×4, H = 40) and a larger one (100×20, H = 110). The
peer (bench/irl_peer.py, in bench/.venv-imitation) builds the MDP and saves its P, ρ₀ and reward;
ours runs on exactly those arrays. Reported per size:

- seconds per iteration (one backward pass, one forward pass, one Adam step), timed over N
  iterations after a warm-up run that pays torch's lazy initialisation, the median of `repeats`
  fresh runs (this VM's timings wander by ±20 % from run to run), one torch thread;
- iterations until the learned occupancy is within 1e-3 (L∞) of the expert's, at Adam lr 0.1
  for both (fewer iterations than imitation's default 1e-2, on both sides: bench/RESULTS.md).
  Each side imitates the soft-optimal expert of its own model: imitation's planner leaves the reward of
  the final state s_H out (Q_{H-1} = r), ours counts it as the notes do (V_H = r), so neither
  can reach the other's expert exactly. On 100×20 imitation's count would take hours (3 s per
  iteration), so only ours is counted there.

Target (issue): ours ≤ 0.3× imitation's time per iteration.

`--continuous [--seeds 0 1 2] [--envs ...]` instead runs the continuous pipeline as a user
would through the library's jobs: `train irl --method gcl` on the bundled demos, then `train ppo
--reward` from scratch, then the deterministic evaluation on the true reward; it prints each
stage's wall time and the true return normalised between a uniform random policy (0) and the
demos (1). No peer: imitation has no continuous MaxEnt IRL.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch

from bc import BENCH, ROOT, _peer_env, ensure_imitation_venv
from imitation.algorithms.gcl import GCLConfig
from imitation.algorithms.maxent_irl import MaxEntIRL, MaxEntIRLConfig
from imitation.data.dataset import DemoDataset
from imitation.envs.make import make_env
from imitation.envs.tabular import TabularMDP
from imitation.envs.tabular_planning import Dynamics, soft_optimal_policy, state_visitation
from imitation.evaluation.policy import evaluate_policy
from imitation.jobs.irl import gcl_job
from imitation.jobs.loop import run as run_learner
from imitation.jobs.ppo import ppo_job
from imitation.jobs.presets import ppo_config, preset
from imitation.rewards import make_reward_model

CASES = (
    {"width": 7, "height": 4, "horizon": 40, "iterations": 300, "repeats": 5, "convergence_max_iter": 20_000},
    {"width": 100, "height": 20, "horizon": 110, "iterations": 10, "repeats": 1, "convergence_max_iter": 0},
)
LEARNING_RATE = 0.1
# env id → (demo file, GCL steps, retraining steps): the defaults of `train irl --method gcl` and `eval reward`.
CONTINUOUS = {
    env_id: (demos, preset(env_id).irl_steps, preset(env_id).retrain_steps)
    for env_id, demos in (("imitation/CartPoleFixedHorizon-v0", "CartPoleFixedHorizon-v0.mcap"), ("Pendulum-v1", "Pendulum-v1.mcap"))
}
OUR_CONVERGENCE_CAP = 20_000
TARGET = 0.3


def run_peer(python: Path, case: dict, workdir: Path) -> tuple[dict, Path]:
    spec = {**case, "lr": LEARNING_RATE, "seed": 0, "discount": 1.0, "mdp_out": str(workdir / f"mdp-{case['width']}x{case['height']}.npz")}
    spec_path, result_path = workdir / "spec.json", workdir / "result.json"
    spec_path.write_text(json.dumps(spec))
    # cwd=BENCH keeps our checkout off the peer's sys.path, so `imitation` is theirs there.
    completed = subprocess.run([str(python), str(BENCH / "irl_peer.py"), str(spec_path), str(result_path)], cwd=BENCH, env=_peer_env(), capture_output=True, text=True)
    if completed.returncode != 0:
        raise SystemExit(f"bench/irl.py: peer failed ({completed.returncode}):\n{completed.stderr[-4000:]}")
    return json.loads(result_path.read_text()), Path(spec["mdp_out"])


def load_mdp(path: Path) -> TabularMDP:
    arrays = np.load(path)
    return TabularMDP(
        transition=arrays["transition"], initial=arrays["initial"], features=arrays["features"].astype(np.float64),
        reward=arrays["reward"], horizon=int(arrays["horizon"]),
    )


def run_ours(mdp: TabularMDP, iterations: int, repeats: int, count_convergence: bool) -> dict:
    torch.set_num_threads(1)
    dynamics = Dynamics.of(mdp.transition)
    expert = state_visitation(dynamics, mdp.initial, soft_optimal_policy(mdp), horizon=mdp.horizon, discount=1.0)

    def fresh_model():
        torch.manual_seed(0)
        return make_reward_model(gym.spaces.Discrete(mdp.n_states), gym.spaces.Discrete(mdp.n_actions), feature_table=mdp.features, hidden_sizes=[])

    def train(config: MaxEntIRLConfig) -> list[dict[str, float]]:
        """The learner built (its Adam too) and run to its end: the rows of its iterations."""
        return run_learner(MaxEntIRL(mdp, expert, fresh_model(), config))

    train(MaxEntIRLConfig(iterations=3, tolerance=0.0))  # warm-up
    timings = []
    for _ in range(repeats):
        config = MaxEntIRLConfig(iterations=iterations, tolerance=0.0, learning_rate=LEARNING_RATE)
        started = time.perf_counter()
        train(config)
        timings.append((time.perf_counter() - started) / iterations)
    result = {"seconds_per_iteration": float(np.median(timings)), "iterations_to_1e-3": None, "final_linf": None}
    if count_convergence:
        history = train(MaxEntIRLConfig(iterations=OUR_CONVERGENCE_CAP, tolerance=1e-3, learning_rate=LEARNING_RATE))
        result["final_linf"] = history[-1]["occupancy_error"]
        # Our loop checks the error before each update, as imitation's does: the count is the
        # number of updates taken when the bound is first met.
        result["iterations_to_1e-3"] = len(history) - 1 if result["final_linf"] <= 1e-3 else None
    return result


def run_continuous(env_id: str, seed: int, workdir: Path) -> dict:
    demos, irl_steps, retrain_steps = CONTINUOUS[env_id]
    demos = str(ROOT / "datasets" / demos)
    started = time.perf_counter()
    gcl_job([demos], env_id, GCLConfig(seed=seed), ppo_config(env_id, beside_irl=True, total_steps=irl_steps, seed=seed), workdir / "gcl", progress=False)
    irl_seconds = time.perf_counter() - started
    retrained = ppo_job(
        ppo_config(env_id, learned_reward=True, total_steps=retrain_steps, seed=seed), workdir / "ppo", reward_run=str(workdir / "gcl"), progress=False,
    )
    env = make_env(env_id)
    env.action_space.seed(0)
    random = evaluate_policy(lambda observation: env.action_space.sample(), env, episodes=10, seed=0)["mean_return"]
    expert = float(np.mean([facts.episode_return for facts in DemoDataset([demos]).episodes]))
    learned = retrained["eval"]["mean_return"]
    return {"irl_seconds": irl_seconds, "retrain_seconds": retrained["seconds"], "return": learned, "normalized": (learned - random) / (expert - random)}


def main_continuous(env_ids: list[str], seeds: list[int]) -> None:
    torch.set_num_threads(1)
    print(f"{'env':>34} | seed | {'GCL s':>6} | {'retrain s':>9} | {'true return':>11} | normalised")
    for env_id in env_ids:
        for seed in seeds:
            with tempfile.TemporaryDirectory(prefix="bench-gcl-") as workdir:
                result = run_continuous(env_id, seed, Path(workdir))
            print(f"{env_id:>34} | {seed:4d} | {result['irl_seconds']:6.0f} | {result['retrain_seconds']:9.0f} | {result['return']:11.1f} | {result['normalized']:.2f}")
            sys.stdout.flush()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--continuous", action="store_true", help="run GCL → PPO from scratch instead of the tabular comparison")
    parser.add_argument("--envs", nargs="+", default=list(CONTINUOUS), choices=list(CONTINUOUS), help="continuous envs (default: both)")
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2], help="continuous seeds (default: 0 1 2)")
    args = parser.parse_args()
    if args.continuous:
        main_continuous(args.envs, args.seeds)
        return
    python, versions = ensure_imitation_venv()
    if python is None:
        raise SystemExit(f"bench/irl.py: no peer: {versions}")
    print(f"peer: {versions}; ours: torch {torch.__version__}, numpy {np.__version__}; 1 thread each")
    print(f"{'MDP':>22} | {'ours s/it':>10} | {'theirs s/it':>11} | {'ratio':>6} | {'ours its→1e-3':>13} | {'theirs its→1e-3':>15}")
    with tempfile.TemporaryDirectory(prefix="bench-irl-") as workdir:
        for case in CASES:
            theirs, mdp_path = run_peer(python, case, Path(workdir))
            mdp = load_mdp(mdp_path)
            ours = run_ours(mdp, case["iterations"], case["repeats"], count_convergence=True)
            mdp_path.unlink()
            ratio = ours["seconds_per_iteration"] / theirs["seconds_per_iteration"]
            name = f"{case['width']}×{case['height']} H={case['horizon']} ({mdp.n_states} s)"
            print(f"{name:>22} | {ours['seconds_per_iteration']:10.5f} | {theirs['seconds_per_iteration']:11.5f} | {ratio:5.3f}× | "
                  f"{ours['iterations_to_1e-3']!s:>13} | {theirs['iterations_to_1e-3']!s:>15}  {'met' if ratio <= TARGET else 'NOT met'} (target ≤ {TARGET}×)")
            sys.stdout.flush()


if __name__ == "__main__":
    main()
