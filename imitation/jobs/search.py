"""`train hill-climb`, `train cem`, `train cmaes`: gradient-free policy search into a run directory.

The run keeps the search's centre (hill climbing's incumbent, the mean of CEM and CMA-ES; see
`imitation.algorithms.policy_search` for why not the best single candidate) as an `ActorCritic`,
so `eval policy RUN_DIR --env ID` evaluates it like any other policy.
"""

from __future__ import annotations

import os
from contextlib import closing
from typing import Any

from imitation.algorithms.policy_search import PolicySearch, SearchConfig
from imitation.envs.make import make_env
from imitation.evaluation.plots import plot_curve
from imitation.jobs.run_config import RunConfig, config_json
from imitation.jobs.run_directory import final_evaluation, save_policy, train_to_end, training_run
from imitation.seeding import seed_everything

# Per-environment SearchConfig fields, over the config's defaults (a linear policy, 16 candidates,
# one episode each, CEM's σ₀ = 0.5). The figures behind them are in tests/algorithms/test_policy_search.py's
# slow tests.
PRESETS: dict[str, dict[str, Any]] = {
    "CartPole-v1": {"total_steps": 50_000},
    # A linear policy cannot both pump energy into the swing and hold the pendulum up: a small
    # MLP can. A wider population and CEM's extra variance kept longer (to the last generation of
    # the budget) keep the search from settling on a policy that swings up from some starts only.
    "Pendulum-v1": {
        "total_steps": 500_000,
        "hidden_sizes": [8],
        "population": 24,
        "extra_noise": 0.2,
        "extra_noise_generations": 100,
    },
}
DEFAULT_STEPS = 100_000


def search_config(env_id: str, method: str, **fields: Any) -> SearchConfig:
    """A SearchConfig for `env_id` and `method`: its preset, then `fields` over it."""
    settings = {"total_steps": DEFAULT_STEPS} | PRESETS.get(env_id, {})
    return SearchConfig(env_id=env_id, method=method, **settings | fields)


def search_job(config: SearchConfig, out: str | os.PathLike, *, progress: bool = True, resume: bool = False) -> dict[str, Any]:
    """Search into run directory `out`; the metrics also written to metrics.json. `resume`
    continues the interrupted run in `out`.partial from its checkpoint."""
    config.validate()
    seed_everything(config.seed)
    run_config = RunConfig(kind="search", env_id=config.env_id, search=config_json(config))
    with training_run(out, run_config, resume=resume) as run:
        learner = PolicySearch(config)
        seconds = train_to_end(run, learner, progress=progress)
        save_policy(run, learner.policy)
        plot_curve(
            run.file("learning_curve.png"),
            run.history,
            x="step",
            ys=["return", "best_return", "population_return"],
            title=f"{learner.name} on {config.env_id}",
        )
        with closing(make_env(config.env_id)) as env:
            evaluation = final_evaluation(learner.policy, env)
        metrics = {
            "env_id": config.env_id,
            "method": config.method,
            "steps": learner.global_step,
            "generations": learner.generations,
            "episodes": learner.episodes,
            "parameters": learner.dimension,
            "seconds": seconds,
            "steps_per_second": learner.global_step / seconds if seconds > 0 else None,
            "final_train_return": run.history[-1]["return"] if run.history else None,
            "eval": evaluation,
        }
        run.finish(metrics)
    return {"run": str(run.path), **metrics}
