"""`record`: an expert's episodes in a gymnasium env, written to an MCAP demo file as they end."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from imitation.data.mcap.source import refuse_url
from imitation.data.mcap.writer import DemoWriter
from imitation.data.recorder import RecordEpisodes, run_episodes
from imitation.envs.action_noise import ActionNoise
from imitation.envs.make import control_period
from imitation.envs.pixels import PixelObservation, PixelRecipe, expert_on_state
from imitation.errors import ImitationError
from imitation.experts.load import close_expert, load_expert, make_env_for_expert
from imitation.jobs.record_config import RecordConfig


def record_job(
    config: RecordConfig,
    out: str | os.PathLike,
    *,
    pixels: PixelRecipe | None = None,
    speed: float = 1.0,
    progress: bool = True,
) -> dict[str, Any]:
    """Record `config.episodes` episodes of the expert `config.expert` in `config.env_id` (episode
    i reset with seed `config.seed + i`) to `out`; their returns. Each episode is durable the
    moment it ends: Ctrl-C keeps the finished ones (KeyboardInterrupt says how many).

    With `pixels` the observations are rendered frames beside the env's own observation
    (`PixelObservation`), which the expert acts on; `frame_stack` is stored as the number of
    frames learners stack by default (single frames are what the file holds).

    With `action_noise` ε the env executes a random action with probability ε while the file
    stores the expert's action at every step (`ActionNoise`, DART): demos of the states next to
    the expert's path, labelled. With `noise_bias` β a noisy step executes the episode's own
    random action with probability β: noise with a mean, which the expert is recorded fighting.
    A person's window (`--expert keyboard|gamepad`) runs at `speed` times real time and is closed
    at the end."""
    refuse_url(out)
    out = Path(out)
    if out.is_dir():
        raise ImitationError(f"--out {out}: is a directory; give a file name such as {out / 'demos.mcap'}")
    config.validate(pixels is not None)
    env_id, expert_spec, seed, frame_stack = config.env_id, config.expert, config.seed, config.frame_stack
    action_noise, noise_bias = config.action_noise, config.noise_bias
    env = make_env_for_expert(env_id, expert_spec, pixels=pixels is not None)
    policy = None
    try:
        policy = load_expert(expert_spec, env, seed=seed, speed=speed)
        metadata: dict[str, Any] = {"expert": expert_spec, "seed": seed}
        if pixels is not None:
            env = PixelObservation(env, pixels)
            policy = expert_on_state(policy, env)
            metadata["pixels"] = pixels.to_json() | {"frame_stack": frame_stack}
        if action_noise > 0:
            metadata["action_noise"] = action_noise
            metadata["actions"] = (
                f"the expert's labels; with probability {action_noise} the env executed a uniformly random action instead"
            )
            if noise_bias > 0:
                metadata["noise_bias"] = noise_bias
                metadata["actions"] = (
                    f"the expert's labels; with probability {action_noise} the env executed a random action instead: "
                    f"with probability {noise_bias} the episode's own one, else a uniform one"
                )
        writer = DemoWriter(
            out,
            env_id=env_id,
            observation_space=env.observation_space,
            action_space=env.action_space,
            dt=control_period(env),
            source=f"imitation record --expert {expert_spec}",
            metadata=metadata,
            end_flags={"decided": "env"},  # RecordEpisodes keeps the env's own terminated/truncated
            durable=True,
            compression=config.compression,
            image_codec=config.image_codec,
        )
        try:
            with writer:
                acted = ActionNoise(env, action_noise, seed=seed, bias=noise_bias) if action_noise > 0 else env
                returns = run_episodes(
                    RecordEpisodes(acted, writer), policy, episodes=config.episodes, seed=seed, progress=progress
                )
        except KeyboardInterrupt:
            kept = writer.episodes_written
            raise KeyboardInterrupt(
                f"kept {kept} finished episode(s) in {out}" if kept else "no episode had finished; nothing written"
            ) from None
    finally:
        env.close()
        if policy is not None:
            close_expert(policy)
    return {
        "out": str(out),
        "env_id": env_id,
        "expert": expert_spec,
        "episodes": len(returns),
        "mean_return": sum(returns) / len(returns),
        "min_return": min(returns),
        "max_return": max(returns),
    }
