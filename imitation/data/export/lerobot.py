"""Demo file → a LeRobotDataset (codebase v3.0), written with lerobot's own writer.

An episode of T steps becomes T + 1 frames, so that no observation is lost: frame t holds
observation t, action t and `next.reward` = reward t; the last frame holds the final
observation, repeats the last action (LeRobot needs one in every frame; `imitation convert
--from lerobot` drops it again) and has `next.done` set when the episode terminated. Feature
names: `observation.state` (or `observation.<key>` for each key of a Dict space), `action`,
`next.reward` (float64), `next.done`. Scalars (Discrete actions, rewards) have shape (1,).

Camera observations (uint8 (H, W, 3) leaves) become LeRobot video features of shape (H, W, 3),
encoded by lerobot's writer with its default RGB encoder (AV1 by libsvtav1, crf 30, through
PyAV; H.264 where SVT-AV1 cannot, see `_encoder`): frames are written as PNG files first and
each episode encoded when it is saved (lerobot's streaming encoder drops frames when it falls
behind). A bare image observation is `observation.image`. Video is lossy: converted back, the
frames are close to, not equal to, the demos' (48 dB PSNR on SO-101's wrist camera).

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

from imitation.data.convert.lerobot import SIDECAR, lerobot_quietly
from imitation.data.mcap.format import to_json_text
from imitation.data.mcap.reader import DemoFile
from imitation.data.spaces import space_leaves, space_to_json
from imitation.data.types import Episode, tree_leaves
from imitation.errors import ImitationError
from imitation.output import OutputLock, as_the_umask_allows, check_target, writing
from imitation.progress import progress_over


def _feature_names(space: gym.Space, role: str) -> dict[tuple[str, ...], str]:
    if isinstance(space, gym.spaces.Dict) and any(isinstance(sub, gym.spaces.Dict) for sub in space.spaces.values()):
        raise ImitationError(f"nested Dict {role} spaces cannot be exported to LeRobot")
    if role != "observation":
        return {path: "action" if path == () else f"action.{path[0]}" for path, _, _ in space_leaves(space)}
    bare = (
        "observation.image"
        if _is_camera(np.dtype(space.dtype or "float64"), tuple(space.shape or ()))
        else "observation.state"
    )
    return {path: bare if path == () else f"observation.{path[0]}" for path, _, _ in space_leaves(space)}


def _is_camera(dtype: np.dtype, shape: tuple[int, ...]) -> bool:
    """An RGB frame, channels last: what a LeRobot video feature holds."""
    return dtype == np.uint8 and len(shape) == 3 and shape[2] == 3


def _feature(dtype: np.dtype, shape: tuple[int, ...], role: str) -> dict[str, Any]:
    if role == "observation" and _is_camera(dtype, shape):
        return {"dtype": "video", "shape": shape, "names": ["height", "width", "channel"]}
    return {"dtype": np.dtype(dtype).name, "shape": shape or (1,), "names": None}


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
    for space, names, role in (
        (demo.observation_space, observation_names, "observation"),
        (demo.action_space, action_names, "action"),
    ):
        for path, dtype, shape in space_leaves(space):
            features[names[path]] = _feature(dtype, tuple(shape), role)
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

            videos = [tuple(f["shape"]) for f in features.values() if f["dtype"] == "video"]
            dataset = LeRobotDataset.create(
                repo_id=f"local/{out.name}",
                fps=fps,
                features=features,
                root=partial,
                use_videos=bool(videos),
                # The frames' PNG files are written by threads while the next frames are gathered.
                image_writer_threads=4 if videos else 0,
                rgb_encoder=_encoder(fps, videos),
            )
            try:
                for index, episode in enumerate(
                    progress_over(demo, total=len(demo), desc="export", unit="episode", enabled=progress)
                ):
                    for frame in _frames(episode, observation_names, action_names, features, task):
                        dataset.add_frame(frame)
                        frames += 1
                    _save_episode(dataset, demo, index)
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
        as_the_umask_allows(partial)
        if out.exists():
            out.rmdir()  # empty, checked above
        os.replace(partial, out)
    except BaseException:
        shutil.rmtree(partial, ignore_errors=True)
        raise
    return frames


def _encoder(fps: int, shapes: list[tuple[int, ...]]) -> Any:
    """lerobot's default video encoder (AV1 by SVT-AV1, None here) where it works, else H.264 in
    4:4:4 (any frame size, odd ones too): SVT-AV1 refuses more than 240 fps, and (as PyAV 15.1
    builds it) dies of SIGFPE on frames narrower than 25 pixels (measured)."""
    if fps <= 240 and all(shape[1] >= 32 for shape in shapes):
        return None
    from lerobot.configs import RGBEncoderConfig

    return RGBEncoderConfig(vcodec="h264", pix_fmt="yuv444p")


def _save_episode(dataset: Any, demo: DemoFile, index: int) -> None:
    """lerobot's save_episode (which encodes the episode's videos), its failures one line."""
    import av

    try:
        dataset.save_episode()
    except (av.error.FFmpegError, RuntimeError, ValueError, OSError) as error:
        raise ImitationError(
            f"{demo.path}: episode {index}: lerobot could not save it ({type(error).__name__}: {str(error)[:200]})"
        ) from None


def _frames(episode: Episode, observation_names: dict, action_names: dict, features: dict, task: str) -> Any:
    """The T + 1 frames of one episode, as lerobot's add_frame wants them (arrays of the feature shape)."""
    steps = len(episode)
    observations = dict(tree_leaves(episode.observations))
    actions = dict(tree_leaves(episode.actions))

    def shaped(value: npt.ArrayLike, name: str) -> np.ndarray:
        if features[name]["dtype"] == "video":
            return np.asarray(value)  # uint8 (H, W, 3) already
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
