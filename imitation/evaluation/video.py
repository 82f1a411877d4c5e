"""One episode of a policy as a video: .gif through Pillow, .mp4 (H.264) through PyAV."""

from __future__ import annotations

import os
import warnings
from collections.abc import Callable
from pathlib import Path

import gymnasium as gym
import numpy as np

from imitation.envs.make import make_env
from imitation.envs.rollout import Policy, start_episode
from imitation.errors import ImitationError

VIDEO_SUFFIXES = (".gif", ".mp4")


def record_video(
    env_id: str,
    policy: Policy,
    path: str | os.PathLike,
    *,
    seed: int,
    observe: Callable[[gym.Env], gym.Env] | None = None,
) -> dict[str, float]:
    """Play one episode (reset with `seed`) rendered as rgb_array frames and write them to
    `path` (written under a temporary name, then renamed). Returns its return, length and fps.
    `observe` wraps the rendering env into the one the policy acts in (its rendered frames, frame
    stacks, the previous action: `imitation.policies.observed_rendering`)."""
    path = Path(path)
    if path.suffix.lower() not in VIDEO_SUFFIXES:
        raise ImitationError(f"--video {path}: the file name must end in {' or '.join(VIDEO_SUFFIXES)}")
    # pygame's renderers need no display for rgb_array frames; without these it complains on stderr.
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
    os.environ.setdefault("SDL_AUDIODRIVER", "dummy")
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="pkg_resources is deprecated")  # raised by importing pygame; harmless
        frames, episode_return, fps = _play(env_id, policy, seed, observe)
    temporary = path.with_name(f".{path.name}.partial{path.suffix}")
    try:
        (_write_gif if path.suffix.lower() == ".gif" else _write_mp4)(temporary, frames, fps)
        os.replace(temporary, path)
    except OSError as error:
        temporary.unlink(missing_ok=True)
        raise ImitationError(f"--video {path}: cannot write: {error.strerror or error}") from None
    return {"return": episode_return, "frames": len(frames), "fps": fps}


def _play(
    env_id: str, policy: Policy, seed: int, observe: Callable[[gym.Env], gym.Env] | None
) -> tuple[list[np.ndarray], float, float]:
    rendered = make_env(env_id, render_mode="rgb_array")
    env = observe(rendered) if observe is not None else rendered
    try:
        frames, episode_return = [], 0.0
        observation, _ = env.reset(seed=seed)
        start_episode(policy)
        frames.append(_frame(env.render(), env_id))
        done = False
        while not done:
            observation, reward, terminated, truncated, _ = env.step(policy(observation))
            episode_return += float(reward)
            frames.append(_frame(env.render(), env_id))
            done = terminated or truncated
        return frames, episode_return, float(env.metadata.get("render_fps") or 30)
    finally:
        env.close()


def _frame(frame: object, env_id: str) -> np.ndarray:
    if not isinstance(frame, np.ndarray) or frame.ndim != 3:
        raise ImitationError(f"--video: {env_id} does not render rgb_array frames")
    return frame


def _write_gif(path: Path, frames: list[np.ndarray], fps: float) -> None:
    from PIL import Image

    images = [Image.fromarray(frame) for frame in frames]
    images[0].save(path, format="GIF", save_all=True, append_images=images[1:], duration=round(1000 / fps), loop=0)


def _write_mp4(path: Path, frames: list[np.ndarray], fps: float) -> None:
    import av

    # H.264 in yuv420p needs even dimensions: crop the odd row or column.
    height, width = (frames[0].shape[0] // 2) * 2, (frames[0].shape[1] // 2) * 2
    with av.open(str(path), mode="w", format="mp4") as container:
        stream = container.add_stream("libx264", rate=round(fps))
        stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
        for frame in frames:
            for packet in stream.encode(
                av.VideoFrame.from_ndarray(np.ascontiguousarray(frame[:height, :width]), format="rgb24")
            ):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
