"""The methods of `train irl --method`, one entry each: the configs whose flags it takes, how it
trains from what the command was asked, the line it prints, and a sweep's default metric. A new
method is its learner's modules and one `register(IRLMethod(...))`: the command line (its
`--method` choices and flags) and sweeps read this table.

Light on purpose, like the configs (the jobs are imported when a method trains): the command line
reads it to build `train irl --help`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from imitation.algorithms.adversarial_config import AdversarialConfig
from imitation.algorithms.apprenticeship_config import ApprenticeshipConfig
from imitation.algorithms.gcl_config import GCLConfig
from imitation.algorithms.maxent_irl_config import MaxEntIRLConfig
from imitation.algorithms.ppo_config import PPOConfig

RETURN = ("return", "max", "last")
DEFAULT_METHOD = "mce"
# The PPO beside a reward being learnt (gcl, airl, gail) takes only its length from the flags.
BESIDE_PPO = (PPOConfig, ("total_steps",))


@dataclass(frozen=True)
class IRLRun:
    """What `train irl` was asked: the method, its demos, env and run directory, and per config
    class the fields its flags set."""

    method: str
    demos: list[str]
    env_id: str
    out: str
    settings: Mapping[type, dict[str, Any]]
    seed: int | None = None  # --seed, which every method's config takes
    progress: bool = True
    resume: bool = False
    workers: Any = None  # imitation.ray_engine.Workers, or None
    warm_start: str | None = None

    def config(self, config: type, **fields: Any) -> Any:
        """`config` with `fields`, then the flags given over them."""
        return config(**fields | self.settings.get(config, {}))


@dataclass(frozen=True)
class IRLMethod:
    """One method. `configs` are (config, the fields that are its flags, None: all); `flag_defaults`
    how its help names a default the config's does not say. `rollouts`: it runs PPO's rollouts,
    which `--workers` spreads; `discriminator`: it trains a discriminator, which the
    discriminator's flags and `--warm-start` set."""

    name: str
    configs: tuple[tuple[type, tuple[str, ...] | None], ...]
    train: Callable[[IRLRun], dict[str, Any]]
    describe: Callable[[IRLRun, dict[str, Any]], str]
    metric: tuple[str, str, str] = RETURN
    flag_defaults: Mapping[str, str] = field(default_factory=dict)
    rollouts: bool = False
    discriminator: bool = False


IRL_METHODS: dict[str, IRLMethod] = {}


def register(method: IRLMethod) -> None:
    """Add a method `train irl --method` offers (a later one of the same name replaces it)."""
    IRL_METHODS[method.name] = method


def _tabular(run: IRLRun) -> dict[str, Any]:
    from imitation.jobs.irl import tabular_irl_job

    config = run.config(MaxEntIRLConfig, method=run.method)
    return tabular_irl_job(run.demos, run.env_id, config, run.out, progress=run.progress, resume=run.resume)


def _describe_tabular(run: IRLRun, result: dict[str, Any]) -> str:
    return (
        f"{run.method} IRL on {run.env_id}: {result['iterations']} iterations, occupancy error "
        f"{result['occupancy_error']:.2e}; the soft-optimal policy for the learned reward earns "
        f"{result['learned_policy_return']:.2f} (expert {result['expert_return']:.2f}, random "
        f"{result['random_return']:.2f}, normalised {result['normalized_return']:.3f}); run: {result['run']}"
    )


def ppo_beside_irl(run: IRLRun) -> PPOConfig:
    """The PPOConfig of gcl, gail and airl: the env's preset for a policy beside a reward being
    learnt, its IRL length, the flags, and the frames the demos were recorded with."""
    from imitation.jobs.irl import recorded_observation
    from imitation.jobs.presets import ppo_config, preset

    seed = {} if run.seed is None else {"seed": run.seed}
    fields = {"total_steps": preset(run.env_id).irl_steps} | run.settings.get(PPOConfig, {}) | seed
    return ppo_config(run.env_id, beside_irl=True, **fields | recorded_observation(run.demos))


def _gcl(run: IRLRun) -> dict[str, Any]:
    from imitation.jobs.irl import gcl_job

    return gcl_job(
        run.demos,
        run.env_id,
        run.config(GCLConfig),
        ppo_beside_irl(run),
        run.out,
        progress=run.progress,
        resume=run.resume,
        workers=run.workers,
    )


def _describe_gcl(run: IRLRun, result: dict[str, Any]) -> str:
    evaluation = result["eval"]
    return (
        f"GCL on {run.env_id}: {result['steps']} PPO steps in {result['seconds']:.0f} s; the maximum-entropy sampler "
        f"trained alongside (not for use) earns {evaluation['mean_return']:.1f} ± {evaluation['std_return']:.1f} (demos "
        f"{result['demo_return']:.1f}); reward model for `train ppo --reward`: {result['run']}"
    )


def _adversarial(run: IRLRun) -> dict[str, Any]:
    from imitation.jobs.irl import adversarial_job

    return adversarial_job(
        run.demos,
        run.env_id,
        run.config(AdversarialConfig, method=run.method),
        ppo_beside_irl(run),
        run.out,
        progress=run.progress,
        resume=run.resume,
        workers=run.workers,
        warm_start=run.warm_start,
    )


def _describe_adversarial(run: IRLRun, result: dict[str, Any]) -> str:
    evaluation = result["eval"]
    reward = "g" if run.method == "airl" else "−log(1 − D), not a recovered reward"
    return (
        f"{run.method.upper()} on {run.env_id}: {result['steps']} PPO steps in {result['seconds']:.0f} s; the policy "
        f"earns {evaluation['mean_return']:.1f} ± {evaluation['std_return']:.1f} (demos {result['demo_return']:.1f}), "
        f"discriminator accuracy {result['demo_accuracy']:.2f} on demos, {result['sample_accuracy']:.2f} on samples; "
        f"policy for `eval policy` and reward ({reward}) for `train ppo --reward`: {result['run']}"
    )


def _apprenticeship(run: IRLRun) -> dict[str, Any]:
    from imitation.jobs.apprenticeship import apprenticeship_job
    from imitation.jobs.presets import ppo_config

    config = run.config(ApprenticeshipConfig)
    # The PPO solver's steps per iteration are ApprenticeshipConfig's, so --steps is not PPOConfig's here.
    solver = ppo_config(run.env_id, learned_reward=True, seed=config.seed, total_steps=config.solver_steps)
    return apprenticeship_job(run.demos, run.env_id, config, solver, run.out, progress=run.progress, resume=run.resume)


def _describe_apprenticeship(run: IRLRun, result: dict[str, Any]) -> str:
    mixture = result["mixture"]
    return (
        f"apprenticeship learning on {run.env_id}: {result['iterations']} iterations, ‖μ_E - μ̄‖/‖μ_E‖ = "
        f"{result['relative_feature_distance']:.4f}; the mixture of {len(mixture['lambdas'])} policies earns "
        f"{mixture['return']:.2f} (normalised {mixture['normalized_return']:.3f}); reward and policy (member "
        f"{result['chosen_member']}) in: {result['run']}"
    )


OCCUPANCY = ("occupancy_error", "min", "last")
IRL_STEPS = {"total_steps": "the env's preset, 200000 where none"}
for name in ("maxent", "mce"):
    register(IRLMethod(name, ((MaxEntIRLConfig, None),), _tabular, _describe_tabular, OCCUPANCY))
register(IRLMethod("gcl", ((GCLConfig, None), BESIDE_PPO), _gcl, _describe_gcl, flag_defaults=IRL_STEPS, rollouts=True))
for name in ("airl", "gail"):
    register(
        IRLMethod(
            name,
            ((AdversarialConfig, None), BESIDE_PPO),
            _adversarial,
            _describe_adversarial,
            flag_defaults=IRL_STEPS,
            rollouts=True,
            discriminator=True,
        )
    )
register(
    IRLMethod(
        "apprenticeship",
        ((ApprenticeshipConfig, None),),
        _apprenticeship,
        _describe_apprenticeship,
        ("relative_distance", "min", "last"),
    )
)
