"""`record`: an expert's episodes in a gymnasium env, written to an MCAP demo file as they end."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from imitation.data.mcap.writer import DemoWriter
from imitation.data.recorder import RecordEpisodes, run_episodes
from imitation.envs.make import control_period
from imitation.errors import ConfigError, ImitationError
from imitation.experts.load import load_expert, make_env_for_expert


def record_job(
    env_id: str,
    expert_spec: str,
    out: str | os.PathLike,
    *,
    episodes: int,
    seed: int = 0,
    compression: str = "zstd",
    progress: bool = True,
) -> dict[str, Any]:
    """Record `episodes` episodes of `expert_spec` in `env_id` (episode i reset with seed
    `seed + i`) to `out`; their returns. Each episode is durable the moment it ends: Ctrl-C
    keeps the finished ones (KeyboardInterrupt says how many)."""
    out = Path(out)
    if out.is_dir():
        raise ImitationError(f"--out {out}: is a directory; give a file name such as {out / 'demos.mcap'}")
    if episodes < 1:
        raise ConfigError("episodes", f"must be at least 1, got {episodes}", owner="record")
    env = make_env_for_expert(env_id, expert_spec)
    try:
        policy = load_expert(expert_spec, env, seed=seed)
        writer = DemoWriter(
            out,
            env_id=env_id,
            observation_space=env.observation_space,
            action_space=env.action_space,
            dt=control_period(env),
            source=f"imitation record --expert {expert_spec}",
            metadata={"expert": expert_spec, "seed": seed},
            end_flags={"decided": "env"},  # RecordEpisodes keeps the env's own terminated/truncated
            durable=True,
            compression=compression,
        )
        try:
            with writer:
                returns = run_episodes(RecordEpisodes(env, writer), policy, episodes=episodes, seed=seed, progress=progress)
        except KeyboardInterrupt:
            kept = writer.episodes_written
            raise KeyboardInterrupt(
                f"kept {kept} finished episode(s) in {out}" if kept else "no episode had finished; nothing written"
            ) from None
    finally:
        env.close()
    return {
        "out": str(out),
        "env_id": env_id,
        "expert": expert_spec,
        "episodes": len(returns),
        "mean_return": sum(returns) / len(returns),
        "min_return": min(returns),
        "max_return": max(returns),
    }
