"""Peer side of the MCE IRL benchmark: HumanCompatibleAI/imitation 1.0.1's tabular MCEIRL.

Runs under bench/.venv-imitation/bin/python (Python 3.11, seals 0.2.1), where `imitation` is
HumanCompatibleAI's package, never ours: start it without our checkout on PYTHONPATH, e.g.
`cd /tmp && /work/main/bench/.venv-imitation/bin/python /work/main/bench/irl_peer.py SPEC RESULT`.

Usage: irl_peer.py SPEC.json RESULT.json. The spec holds width, height, horizon, discount (default
1.0), iterations (N, the MCEIRL iterations timed), repeats (timed runs, median reported; default 1), lr (Adam; imitation's default 1e-2 if absent),
seed, mdp_out and, optionally, convergence_max_iter (default 5000; 0 skips that run). The script
builds seals' CliffWorld with one-hot observations, saves its MDP and the expert's exact occupancy
to mdp_out (an .npz our side runs on), times N iterations of MCEIRL as one train() call, then
counts the iterations a fresh MCEIRL needs to bring the L-infinity occupancy error to 1e-3 or below.

The npz holds transition (S, A, S), initial (S,), reward (S,), features (S, S) float32 identity,
horizon, discount, expert_occupancy (S,): imitation's Dcum, the discounted sum over the horizon+1
rows of expert_occupancy_by_step (horizon + 1, S), state t = 0..horizon.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from imitation.algorithms import mce_irl
from imitation.rewards import reward_nets
from seals.diagnostics.cliff_world import CliffWorldEnv

CONVERGENCE_LINF = 1e-3


class CountingMCEIRL(mce_irl.MCEIRL):
    """MCEIRL that counts its gradient steps: train() returns only the last occupancy measure."""

    steps = 0

    def _train_step(self, obs_mat: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
        self.steps += 1
        return super()._train_step(obs_mat)


def save_mdp(env: CliffWorldEnv, discount: float, path: str) -> np.ndarray:
    """Write the MDP and the expert's exact occupancy to path; return the occupancy (Dcum)."""
    # Soft-optimal policy under the true reward. Note: with pi=None imitation plans with
    # mce_partition_fh's default discount 1.0; `discount` only weights the occupancy rows.
    # MCEIRL's own inner loop makes the same call, so the expert is reachable by it.
    by_step, occupancy = mce_irl.mce_occupancy_measures(env, discount=discount)
    np.savez(
        path,
        transition=env.transition_matrix.astype(np.float64),
        initial=env.initial_state_dist.astype(np.float64),
        reward=env.reward_matrix.astype(np.float64),
        features=env.observation_matrix,
        horizon=env.horizon,
        discount=discount,
        expert_occupancy=occupancy,
        expert_occupancy_by_step=by_step,
    )
    return occupancy


def make_irl(
    env: CliffWorldEnv,
    occupancy: np.ndarray,
    spec: dict[str, Any],
    linf_eps: float,
) -> CountingMCEIRL:
    """A fresh MCEIRL on a linear state reward, seeded identically each call."""
    torch.manual_seed(spec["seed"])
    # Linear reward on the one-hot observation (a tabular reward plus a redundant bias), as in
    # imitation's tests/algorithms/test_mce_irl.py: BasicRewardNet(hid_sizes=[], use_action=False,
    # use_next_state=False, use_done=False). Parameters are float32 (torch's default).
    reward_net = reward_nets.BasicRewardNet(
        env.observation_space,
        env.action_space,
        hid_sizes=[],
        use_action=False,
        use_next_state=False,
        use_done=False,
    )
    return CountingMCEIRL(
        occupancy,
        env,
        reward_net,
        rng=np.random.default_rng(spec["seed"]),
        optimizer_kwargs={"lr": spec["lr"]} if "lr" in spec else None,
        discount=spec.get("discount", 1.0),
        linf_eps=linf_eps,
        grad_l2_eps=0.0,  # only the L-infinity criterion (if any) may stop training early
        log_interval=None,  # no logger dumps inside the timed loop
    )


def time_iterations(env: CliffWorldEnv, occupancy: np.ndarray, spec: dict[str, Any]) -> float:
    """Seconds per iteration: the median over `repeats` train(max_iter=N) calls that cannot stop
    early, each on a fresh MCEIRL, after a 3-iteration warm-up run that pays torch's one-time
    lazy initialisation (ours does the same)."""
    make_irl(env, occupancy, spec, linf_eps=0.0).train(max_iter=3)
    timings = []
    for _ in range(spec.get("repeats", 1)):
        irl = make_irl(env, occupancy, spec, linf_eps=0.0)
        started = time.perf_counter()
        irl.train(max_iter=spec["iterations"])
        timings.append((time.perf_counter() - started) / spec["iterations"])
        assert irl.steps == spec["iterations"], f"stopped early after {irl.steps} iterations"
    return float(np.median(timings))


def iterations_to_converge(
    env: CliffWorldEnv,
    occupancy: np.ndarray,
    spec: dict[str, Any],
) -> tuple[int | None, float | None]:
    """Iterations until imitation's own stopping test sees L-infinity error <= 1e-3, and that error.

    MCEIRL checks the occupancy of the reward before each step's update, so the count is the
    number of steps whose pre-update reward first meets the bound (None if max_iter ran out).
    convergence_max_iter 0 skips the run (None, None): on large grids it would take hours.
    """
    max_iter = spec.get("convergence_max_iter", 5000)
    if max_iter == 0:
        return None, None
    irl = make_irl(env, occupancy, spec, linf_eps=CONVERGENCE_LINF)
    visitations = irl.train(max_iter=max_iter)
    final_linf = float(np.max(np.abs(visitations - occupancy)))
    return (irl.steps if final_linf <= CONVERGENCE_LINF else None), final_linf


def run(spec: dict[str, Any]) -> dict[str, Any]:
    """Build and save the MDP, time MCEIRL, count its iterations to convergence."""
    torch.set_num_threads(1)
    discount = spec.get("discount", 1.0)
    env = CliffWorldEnv(
        width=spec["width"],
        height=spec["height"],
        horizon=spec["horizon"],
        use_xy_obs=False,
    )
    occupancy = save_mdp(env, discount, spec["mdp_out"])
    seconds = time_iterations(env, occupancy, spec)
    iterations, final_linf = iterations_to_converge(env, occupancy, spec)
    return {
        "library": "imitation 1.0.1",
        "width": spec["width"],
        "height": spec["height"],
        "horizon": spec["horizon"],
        "states": env.state_dim,
        "actions": env.action_dim,
        "seconds_per_iteration": seconds,
        "iterations_timed": spec["iterations"],
        "iterations_to_1e-3": iterations,
        "final_linf": final_linf,
        "torch_threads": torch.get_num_threads(),
    }


def main() -> None:
    spec_path, result_path = sys.argv[1], sys.argv[2]
    result = run(json.loads(Path(spec_path).read_text()))
    Path(result_path).write_text(json.dumps(result))


if __name__ == "__main__":
    main()
