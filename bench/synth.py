"""Synthetic HalfCheetah-like demos, written to every format bench/load.py compares.

Run as a script (a subprocess of bench/load.py) to generate one data set:

    python bench/synth.py OUT_DIR --episodes 1000 --steps 1000 --seed 0

It writes our demo file once per chunk compression (DemoWriter: OUT_DIR/ours.mcap with LZ4, the
default, ours-zstd.mcap and ours-plain.mcap), OUT_DIR/lerobot/ (a finalized LeRobotDataset v3.0),
OUT_DIR/npy/*.npy (the raw transition arrays) and, last, OUT_DIR/manifest.json holding write
times and on-disk sizes. bench/load.py treats a directory with a manifest as complete.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

OBS_DIM = 17
ACT_DIM = 6
DT = 0.05  # HalfCheetah-v5: frame_skip 5 × timestep 0.01
FPS = 20  # 1 / DT, what LeRobot stores as the recording rate
ENV_ID = "HalfCheetah-v5"
LEROBOT_REPO_ID = "bench/halfcheetah-synthetic"
LEROBOT_TASK = "run forward"
X_VELOCITY = 8  # index of the root's forward velocity in HalfCheetah's observation


@dataclass(frozen=True)
class Rollouts:
    """Every episode's arrays, stacked: episodes share one length, as HalfCheetah's time limit makes them."""

    observations: np.ndarray  # (E, S + 1, 17) float32: S steps plus the final observation
    actions: np.ndarray  # (E, S, 6) float32 in [-1, 1]
    rewards: np.ndarray  # (E, S) float32

    @property
    def steps(self) -> int:
        return self.actions.shape[1]


def make_rollouts(episodes: int, steps: int, seed: int) -> Rollouts:
    """Smooth, deterministic stand-ins for HalfCheetah rollouts.

    Each observation dimension is a sum of three sinusoids (a gait has a few dominant
    frequencies) plus a small random walk (drift), so consecutive rows are correlated the way
    simulator states are; that matters because it decides how well zstd and snappy compress.
    The reward is HalfCheetah's: forward velocity minus 0.1 × the squared action norm.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(steps + 1, dtype=np.float64) * DT
    shape = (episodes, 1, OBS_DIM, 3)
    amplitude = rng.uniform(0.05, 1.0, shape)
    frequency = rng.uniform(0.2, 3.0, shape)
    phase = rng.uniform(0.0, 2 * np.pi, shape)
    waves = (amplitude * np.sin(2 * np.pi * frequency * t[None, :, None, None] + phase)).sum(axis=-1)
    drift = np.cumsum(rng.normal(0.0, 0.01, (episodes, steps + 1, OBS_DIM)), axis=1)
    observations = (waves + drift).astype(np.float32)
    observations[:, :, X_VELOCITY] += rng.uniform(0.0, 5.0, (episodes, 1)).astype(np.float32)

    action_shape = (episodes, 1, ACT_DIM, 2)
    control = (rng.uniform(0.5, 1.5, action_shape) * np.sin(2 * np.pi * rng.uniform(0.5, 2.0, action_shape) * t[None, :-1, None, None] + rng.uniform(0.0, 2 * np.pi, action_shape))).sum(axis=-1)
    actions = np.tanh(control + rng.normal(0.0, 0.1, control.shape)).astype(np.float32)
    rewards = (observations[:, 1:, X_VELOCITY] - 0.1 * np.square(actions).sum(axis=-1)).astype(np.float32)
    return Rollouts(observations, actions, rewards)


# Our file per chunk compression: the default (LZ4) under the plain name.
OURS = {"ours": "lz4", "ours-zstd": "zstd", "ours-plain": "none"}


def write_ours(rollouts: Rollouts, path: Path, compression: str) -> float:
    """Write with `write_episodes`; returns the seconds it took (Episode objects are views, built inside)."""
    import gymnasium as gym

    from imitation.data.mcap.writer import write_episodes
    from imitation.data.types import Episode

    def episodes() -> Iterator[Episode]:
        for e in range(len(rollouts.actions)):
            # HalfCheetah never terminates: every episode ends at the time limit.
            yield Episode(observations=rollouts.observations[e], actions=rollouts.actions[e], rewards=rollouts.rewards[e], truncated=True)

    start = time.perf_counter()
    write_episodes(
        path,
        episodes(),
        env_id=ENV_ID,
        observation_space=gym.spaces.Box(-np.inf, np.inf, (OBS_DIM,), np.float32),
        action_space=gym.spaces.Box(-1.0, 1.0, (ACT_DIM,), np.float32),
        dt=DT,
        source="bench/synth.py",
        compression=compression,
    )
    return time.perf_counter() - start


def lerobot_features() -> dict[str, dict]:
    """The four per-frame features; shapes are tuples because `add_frame` compares them to ndarray shapes."""
    return {
        "observation.state": {"dtype": "float32", "shape": (OBS_DIM,), "names": None},
        "action": {"dtype": "float32", "shape": (ACT_DIM,), "names": None},
        "next.reward": {"dtype": "float32", "shape": (1,), "names": None},
        "next.done": {"dtype": "bool", "shape": (1,), "names": None},
    }


def write_lerobot(rollouts: Rollouts, root: Path) -> float:
    """Record through LeRobot's documented path (create, add_frame, save_episode, finalize); returns seconds."""
    import datasets

    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    # save_episode runs a datasets `map` per episode: 1,000 progress bars otherwise.
    datasets.disable_progress_bars()
    done = np.zeros((rollouts.steps, 1), dtype=bool)
    done[-1] = True
    start = time.perf_counter()
    # video_backend given so LeRobot does not probe torchcodec (which fails noisily without FFmpeg); there are no videos.
    dataset = LeRobotDataset.create(LEROBOT_REPO_ID, FPS, lerobot_features(), root=root, use_videos=False, video_backend="pyav")
    for e in range(len(rollouts.actions)):
        observations, actions, rewards = rollouts.observations[e], rollouts.actions[e], rollouts.rewards[e]
        for i in range(rollouts.steps):
            dataset.add_frame(
                {
                    "observation.state": observations[i],
                    "action": actions[i],
                    "next.reward": rewards[i : i + 1],
                    "next.done": done[i],
                    "task": LEROBOT_TASK,
                }
            )
        dataset.save_episode()
    dataset.finalize()
    return time.perf_counter() - start


def transition_arrays(rollouts: Rollouts) -> dict[str, np.ndarray]:
    """The flat (N, ...) transitions every loader must produce: obs, action, reward, done."""
    episodes, steps = rollouts.rewards.shape
    done = np.zeros((episodes, steps), dtype=bool)
    done[:, -1] = True
    return {
        "observations": np.ascontiguousarray(rollouts.observations[:, :-1].reshape(-1, OBS_DIM)),
        "actions": rollouts.actions.reshape(-1, ACT_DIM),
        "rewards": rollouts.rewards.reshape(-1),
        "dones": done.reshape(-1),
    }


def write_npy(rollouts: Rollouts, directory: Path) -> float:
    """One .npy file per transition array; returns seconds (flattening included)."""
    start = time.perf_counter()
    directory.mkdir()
    for name, array in transition_arrays(rollouts).items():
        np.save(directory / f"{name}.npy", array)
    return time.perf_counter() - start


def tree_size(path: Path) -> int:
    """Bytes in a file, or in every file under a directory."""
    if path.is_file():
        return path.stat().st_size
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def generate(out: Path, episodes: int, steps: int, seed: int) -> dict:
    """Write all formats into `out` (which must not hold a manifest) and return the manifest."""
    out.mkdir(parents=True, exist_ok=True)
    rollouts = make_rollouts(episodes, steps, seed)
    # A previous run killed half-way leaves partial outputs; LeRobot refuses an existing root.
    for stale in (*(out / f"{name}.mcap" for name in OURS), out / "npy", out / "lerobot"):
        if stale.is_dir():
            shutil.rmtree(stale)
        else:
            stale.unlink(missing_ok=True)
    seconds = {
        **{name: write_ours(rollouts, out / f"{name}.mcap", compression) for name, compression in OURS.items()},
        "lerobot": write_lerobot(rollouts, out / "lerobot"),
        "npy": write_npy(rollouts, out / "npy"),
    }
    manifest = {
        "episodes": episodes,
        "steps": steps,
        "seed": seed,
        "transitions": episodes * steps,
        "write_seconds": seconds,
        "compression": OURS,
        "bytes": {
            **{name: tree_size(out / f"{name}.mcap") for name in OURS},
            "lerobot": tree_size(out / "lerobot"),
            "lerobot_data_parquet": tree_size(out / "lerobot" / "data"),
            "npy": tree_size(out / "npy"),
        },
    }
    (out / "manifest.json").write_text(json.dumps(manifest, indent=2))
    return manifest


def update_ours(out: Path) -> dict:
    """Rewrite those of our files that a data set generated earlier lacks or holds with another
    compression (ours.mcap was zstd before LZ4 became the default), without redoing LeRobot's slow
    recording; their write times and sizes go into the manifest."""
    manifest = json.loads((out / "manifest.json").read_text())
    rollouts = make_rollouts(manifest["episodes"], manifest["steps"], manifest["seed"])
    held = manifest.get("compression", {"ours": "zstd", "ours-plain": "none"})
    for name, compression in OURS.items():
        if held.get(name) != compression or not (out / f"{name}.mcap").exists():
            (out / f"{name}.mcap").unlink(missing_ok=True)
            manifest["write_seconds"][name] = write_ours(rollouts, out / f"{name}.mcap", compression)
            manifest["bytes"][name] = tree_size(out / f"{name}.mcap")
    manifest["compression"] = OURS
    (out / "manifest.json").write_text(json.dumps(manifest, indent=2))
    return manifest


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("out", type=Path)
    parser.add_argument("--episodes", type=int, required=True)
    parser.add_argument("--steps", type=int, required=True)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--ours-only", action="store_true", help="only bring our files of an existing data set up to date")
    args = parser.parse_args()
    if os.environ.get("HF_HUB_OFFLINE") != "1":
        sys.exit("synth.py: run it through bench/load.py, which keeps Hugging Face libraries offline")
    if args.ours_only:
        print(json.dumps(update_ours(args.out)))
    else:
        print(json.dumps(generate(args.out, args.episodes, args.steps, args.seed)))


if __name__ == "__main__":
    main()
