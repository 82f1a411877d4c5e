"""`eval policy`: a run's policy in an env: returns, the return normalised by the demos it
learnt from, and a video of an episode."""

from __future__ import annotations

import os
from contextlib import closing
from typing import Any

from imitation.errors import ImitationError
from imitation.evaluation.policy import evaluate_policy, normalized_return
from imitation.evaluation.video import record_video
from imitation.jobs.evaluate_policy_config import PolicyEvaluationConfig
from imitation.jobs.run_config import RunConfig
from imitation.policies import (
    SingleObservationPolicy,
    acting_env,
    check_policy_fits_env,
    make_acting_env,
    observed_rendering,
)
from imitation.policy_kinds import load_policy
from imitation.runs import read_run


def eval_policy_job(run: str | os.PathLike, env_id: str, settings: PolicyEvaluationConfig | None = None) -> dict[str, Any]:
    """Evaluate run directory `run`'s policy on `settings.episodes` episodes of `env_id` (episode
    i reset with seed `settings.seed + i`), deterministically unless `settings.stochastic`. The
    return is also normalised between a random policy (0) and `settings.demos` (default: those
    the run learnt from) when there are any, the references `eval reward` uses too
    (`reference_returns`); `settings.video` writes episode 0 as .mp4 or .gif."""
    settings = settings or PolicyEvaluationConfig()
    settings.validate()
    _refuse_sb3_zip(run, env_id, settings.episodes, settings.seed)
    policy = load_policy(run)
    config, _ = read_run(run)
    actor = SingleObservationPolicy(policy, deterministic=not settings.stochastic)
    with closing(make_acting_env(policy.config, env_id)) as env:
        policy_env = acting_env(policy, env)
        check_policy_fits_env(policy, policy_env, str(run))
        result = evaluate_policy(actor, policy_env, episodes=settings.episodes, seed=settings.seed)
        demos = settings.demos if settings.demos is not None else RunConfig.from_json(config).existing_demos()
        if demos:
            result |= normalized_return(result, env, demos)
    if settings.video is not None:
        result["video"] = {
            "path": settings.video,
            **record_video(
                env_id,
                actor,
                settings.video,
                seed=settings.seed,
                observe=lambda env: observed_rendering(policy, env),
            ),
        }
    return {"run": str(run), "env_id": env_id, "deterministic": not settings.stochastic, **result}


def _refuse_sb3_zip(run: str | os.PathLike, env_id: str, episodes: int, seed: int) -> None:
    """A stable-baselines3 zip is scored by `record`, which acts with it as an expert: say so."""
    spec = str(run)
    zip_path = spec.removeprefix("sb3:")
    if spec.startswith("sb3:") or (zip_path.endswith(".zip") and os.path.isfile(zip_path)):
        raise ImitationError(
            f"{spec}: eval policy scores a run directory; a stable-baselines3 zip is scored by recording its episodes: "
            f"imitation record --env {env_id} --expert sb3:{zip_path} --episodes {episodes} --seed {seed} --out F.mcap "
            "(it prints their mean, min and max return)"
        )
