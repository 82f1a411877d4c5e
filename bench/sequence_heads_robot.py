"""Benchmark: the sequence heads' held-out multi-step action error on a real robot's recording, beside
today's BC and the hold baseline.

`convert` the Unitree G1 LeRobot v2.1 set (../shared/testdata/lerobot/g1_v21: 100 episodes of
26 joint states and targets at 30 Hz, no env), then `train bc` offline: today's Gaussian BC at its
defaults but for the previous action (off: the policy reads s_t alone, as the heads do), the chunk head and the diffusion head (2 observations, chunks of 16). On the episodes BC
held out (the same seeded split, `split_episodes`), each policy predicts the next H actions from
every step t of every held-out episode, and the error of the k-th, averaged over the joints and the
steps whose a_{t+k} lies inside the episode, is reported for k = 1, 4, 8, 16: the mean absolute error
in the actions' units. The Gaussian BC predicts one step, so its k-th action is the mean of the
policy at s_t (a plan held for H steps); hold repeats a_{t−1} (a_t at an episode's start).

    .venv/bin/python bench/sequence_heads_robot.py [--epochs N] [--threads T]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO / "tests"))
from support import TESTDATA  # noqa: E402

from imitation.data.dataset import DemoDataset  # noqa: E402
from imitation.data.loader import split_episodes  # noqa: E402
from imitation.policy_kinds import load_policy  # noqa: E402

G1 = TESTDATA / "lerobot" / "g1_v21"
HORIZON, HISTORY = 16, 2
STEPS = (1, 4, 8, 16)
HEADS = {
    "gaussian": ["--policy", "actor-critic", "--previous-action", "off"],
    "chunk": ["--policy", "chunk", "--history", str(HISTORY), "--chunk", str(HORIZON), "--hidden", "512,512,512"],
    "diffusion": [
        "--policy",
        "diffusion",
        "--history",
        str(HISTORY),
        "--chunk",
        str(HORIZON),
        "--hidden",
        "512,512,512",
        "--lr",
        "3e-4",
        "--l2",
        "0",
    ],  # fmt: skip
}


def cli(*args: str, threads: int) -> None:
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": str(threads)}
    subprocess.run([sys.executable, str(REPO / "cli.py"), *args], check=True, env=env, stdout=subprocess.DEVNULL)


def plans(policy: torch.nn.Module, observations: np.ndarray, head: str) -> np.ndarray:
    """(T, H, action) planned at every step t of an episode from its history (the first
    observation standing in before the start)."""
    steps = len(observations) - 1
    index = np.clip(np.arange(steps)[:, None] + np.arange(-HISTORY + 1, 1)[None], 0, None)
    history = torch.as_tensor(observations[index], dtype=torch.float32)
    with torch.no_grad():
        if head == "gaussian":
            return np.repeat(policy.point_action(history[:, -1]).numpy()[:, None], HORIZON, axis=1)
        if head == "chunk":
            return policy._env_actions(policy._chunk(history)).numpy()
        return policy.sample(history, torch.Generator().manual_seed(0)).numpy()


def errors(planned: np.ndarray, actions: np.ndarray) -> dict[int, tuple[float, int]]:
    """For each k of STEPS: (the summed absolute error of the k-th planned action over joints and
    in-episode steps, the count of such steps × joints)."""
    out = {}
    for k in STEPS:
        inside = len(actions) - (k - 1)
        if inside <= 0:
            out[k] = (0.0, 0)
            continue
        difference = planned[:inside, k - 1] - actions[k - 1 : k - 1 + inside]
        out[k] = (float(np.abs(difference).sum()), difference.size)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--epochs", type=int, default=100)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    with tempfile.TemporaryDirectory(prefix="bench-sequence-robot-") as folder:
        work = Path(folder)
        demos = work / "g1.mcap"
        cli("convert", str(G1), "--out", str(demos), "--quiet", threads=args.threads)
        dataset = DemoDataset([demos])
        _, held_out = split_episodes(len(dataset), validation_fraction=0.2, seed=args.seed)
        totals: dict[str, dict[int, list[float]]] = {}
        for head, flags in HEADS.items():
            run = work / head
            cli("train", "bc", "--demos", str(demos), *flags, "--epochs", str(args.epochs), "--seed", str(args.seed),
                "--threads", str(args.threads), "--out", str(run), "--quiet", threads=args.threads)  # fmt: skip
            policy = load_policy(run)
            totals[head] = {k: [0.0, 0] for k in STEPS}
            for k_episode in held_out:
                episode = dataset[k_episode]
                for k, (summed, count) in errors(plans(policy, episode.observations, head), episode.actions).items():
                    totals[head][k][0] += summed
                    totals[head][k][1] += count
        totals["hold"] = {k: [0.0, 0] for k in STEPS}
        for k_episode in held_out:
            actions = dataset[k_episode].actions
            previous = np.concatenate([actions[:1], actions[:-1]])
            for k, (summed, count) in errors(np.repeat(previous[:, None], HORIZON, axis=1), actions).items():
                totals["hold"][k][0] += summed
                totals["hold"][k][1] += count
    table = {head: {k: summed / count for k, (summed, count) in by_step.items()} for head, by_step in totals.items()}
    for head, by_step in table.items():
        print(f"{head}: " + ", ".join(f"k={k} {value:.4f}" for k, value in by_step.items()))
    print(json.dumps({"epochs": args.epochs, "held_out_episodes": len(held_out), "mean_absolute_error": table}))


if __name__ == "__main__":
    main()
