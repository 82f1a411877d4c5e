"""Demo file → a LeRobotDataset (codebase v3.0), written with lerobot's own writer.

An episode of T steps becomes T + 1 frames, so that no observation is lost: frame t holds
observation t, action t and `next.reward` = reward t; the last frame holds the final
observation, repeats the last action (LeRobot needs one in every frame; `imitation convert
--from lerobot` drops it again) and has `next.done` set when the episode terminated. Feature
names: `observation.state` (or `observation.<key>` for each key of a Dict space), `action`,
`next.reward` (float64), `next.done`. Scalars (Discrete actions, rewards) have shape (1,).

`meta/imitation.json` keeps what LeRobot has no field for: the env id, the exact spaces, dt,
and each episode's terminated/truncated flags and metadata, so that converting the dataset back
gives the same demos. fps is 1/dt rounded to an integer (LeRobot stores an integer).
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import numpy.typing as npt
from tqdm import tqdm

from imitation.data.convert.lerobot import SIDECAR, lerobot_quietly
from imitation.data.mcap.format import to_json_text
from imitation.data.mcap.reader import DemoFile
from imitation.data.spaces import space_leaves, space_to_json
from imitation.data.types import Episode, tree_leaves
from imitation.errors import ImitationError
from imitation.output import OutputLock, check_target, writing


def _feature_names(space: gym.Space, role: str) -> dict[tuple[str, ...], str]:
    if isinstance(space, gym.spaces.Dict) and any(isinstance(sub, gym.spaces.Dict) for sub in space.spaces.values()):
        raise ImitationError(f"nested Dict {role} spaces cannot be exported to LeRobot")
    base = "observation" if role == "observation" else "action"
    return {
        path: (f"{base}.state" if role == "observation" else base) if path == () else f"{base}.{path[0]}"
        for path, _, _ in space_leaves(space)
    }


def export_lerobot(
    demo_path: str | os.PathLike, out_dir: str | os.PathLike, *, task: str | None = None, progress: bool = True
) -> dict[str, Any]:
    """Write the demos as a LeRobotDataset v3.0 at `out_dir`, which must not exist (or be empty).

    The dataset is built in `<out_dir>.partial` and renamed when lerobot has finalized it."""
    demo = DemoFile(demo_path)
    if len(demo) == 0:
        raise ImitationError(f"{demo.path}: holds no episode to export")
    out = Path(out_dir)
    check_target(out, directory=True, flag="--to lerobot")
    if out.exists() and any(out.iterdir()):
        raise ImitationError(f"{out}: exists and is not an empty folder; choose a new folder for the dataset")
    observation_names = _feature_names(demo.observation_space, "observation")
    action_names = _feature_names(demo.action_space, "action")
    features: dict[str, dict[str, Any]] = {}
    for space, names in ((demo.observation_space, observation_names), (demo.action_space, action_names)):
        for path, dtype, shape in space_leaves(space):
            features[names[path]] = {"dtype": np.dtype(dtype).name, "shape": tuple(shape) or (1,), "names": None}
    features["next.reward"] = {"dtype": "float64", "shape": (1,), "names": None}
    features["next.done"] = {"dtype": "bool", "shape": (1,), "names": None}
    fps = max(1, round(1.0 / demo.dt))
    task = task or demo.env_id or "demonstration"
    partial = out.with_name(out.name + ".partial")
    check_target(partial, directory=True, flag="the partial dataset")
    with OutputLock(out), writing(out):
        shutil.rmtree(partial, ignore_errors=True)
        frames = _write(demo, partial, out, features, observation_names, action_names, fps, task, progress)
    return {
        "out": str(out),
        "to": "lerobot",
        "codebase_version": "v3.0",
        "episodes": len(demo),
        "frames": frames,
        "fps": fps,
        "features": sorted(features),
    }


def _write(
    demo: DemoFile,
    partial: Path,
    out: Path,
    features: dict[str, dict[str, Any]],
    observation_names: dict,
    action_names: dict,
    fps: int,
    task: str,
    progress: bool,
) -> int:
    """Build the dataset in `partial`, then move it to `out`; the number of frames written."""
    frames = 0
    try:
        with lerobot_quietly():
            from lerobot.datasets.lerobot_dataset import LeRobotDataset

            dataset = LeRobotDataset.create(
                repo_id=f"local/{out.name}", fps=fps, features=features, root=partial, use_videos=False
            )
            try:
                for episode in tqdm(
                    demo,
                    total=len(demo),
                    desc="export",
                    unit="episode",
                    disable=None if progress else True,
                    dynamic_ncols=True,
                ):
                    for frame in _frames(episode, observation_names, action_names, features, task):
                        dataset.add_frame(frame)
                        frames += 1
                    dataset.save_episode()
            finally:
                dataset.finalize()
        (partial / SIDECAR).write_text(
            to_json_text(
                {
                    "format": "imitation LeRobot sidecar",
                    "version": 1,
                    "source_file": str(demo.path),
                    "env_id": demo.env_id,
                    "observation_space": space_to_json(demo.observation_space),
                    "action_space": space_to_json(demo.action_space),
                    "dt": demo.dt,
                    "source": demo.source,
                    "user_metadata": demo.user_metadata,
                    "features": {
                        "observation": {"/".join(p): n for p, n in observation_names.items()},
                        "action": {"/".join(p): n for p, n in action_names.items()},
                    },
                    "episodes": [
                        {"length": f.length, "terminated": f.terminated, "truncated": f.truncated, "metadata": f.metadata}
                        for f in demo.episodes
                    ],
                }
            )
            + "\n"
        )
        if out.exists():
            out.rmdir()  # empty, checked above
        os.replace(partial, out)
    except BaseException:
        shutil.rmtree(partial, ignore_errors=True)
        raise
    return frames


def _frames(episode: Episode, observation_names: dict, action_names: dict, features: dict, task: str) -> Any:
    """The T + 1 frames of one episode, as lerobot's add_frame wants them (arrays of the feature shape)."""
    steps = len(episode)
    observations = dict(tree_leaves(episode.observations))
    actions = dict(tree_leaves(episode.actions))

    def shaped(value: npt.ArrayLike, name: str) -> np.ndarray:
        return np.asarray(value, dtype=features[name]["dtype"]).reshape(features[name]["shape"])

    for t in range(steps + 1):
        frame: dict[str, Any] = {"task": task}
        for path, name in observation_names.items():
            frame[name] = shaped(observations[path][t], name)
        for path, name in action_names.items():
            rows = actions[path]
            frame[name] = shaped(rows[min(t, steps - 1)] if steps else np.zeros(rows.shape[1:], dtype=rows.dtype), name)
        frame["next.reward"] = shaped(episode.rewards[t] if t < steps else 0.0, "next.reward")
        frame["next.done"] = shaped(t == steps and episode.terminated, "next.done")
        yield frame
