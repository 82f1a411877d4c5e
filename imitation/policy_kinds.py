"""The policy kinds BC and DAgger can train (`train bc --policy NAME`) and every tool can load:
one entry each, naming how to build the kind from its `PolicyConfig` and how many weights that
config plans (checked against a run's file before anything is built).

A new kind is a module with an `ImitationPolicy` subclass (`imitation.policy_protocol`) and one
`register(PolicyKind(...))`; docs/ARCHITECTURE.md walks through it."""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import gymnasium as gym

from imitation import chunk_policy
from imitation.data.spaces import space_to_json
from imitation.errors import ConfigError, ImitationError, SpaceError
from imitation.mlp import check_weights_cover
from imitation.policies import POLICY_PREFIX, ActorCritic, planned_weights
from imitation.policy_protocol import ACTOR_CRITIC, ImitationPolicy, PolicyConfig
from imitation.runs import read_run


@dataclass(frozen=True)
class PolicyKind:
    """A policy kind: its name (`--policy`, and "kind" in a run's policy config), its
    constructor, the weight count a config plans, whether it reads histories and predicts
    chunks (`--history`, `--chunk`), and whether it can be a deep ensemble (`--members`)."""

    name: str
    build: Callable[[PolicyConfig], ImitationPolicy]
    planned_weights: Callable[[PolicyConfig], int]
    sequences: bool = False
    ensembles: bool = False


POLICY_KINDS: dict[str, PolicyKind] = {}


def register(kind: PolicyKind) -> PolicyKind:
    POLICY_KINDS[kind.name] = kind
    return kind


register(
    PolicyKind(
        ACTOR_CRITIC,
        ActorCritic,
        planned_weights,
    )
)
register(
    PolicyKind(
        "chunk",
        chunk_policy.ActionChunking,
        chunk_policy.planned_weights,
        sequences=True,
    )
)
register(
    PolicyKind(
        "diffusion",
        lambda config: _diffusion().DiffusionPolicy(config),
        lambda config: _diffusion().planned_weights(config),
        sequences=True,
        ensembles=True,
    )
)


def _diffusion() -> Any:
    """imitation.diffusion_policy, imported when a diffusion policy is built (it imports diffusers)."""
    from imitation import diffusion_policy

    return diffusion_policy


def policy_kind(
    name: str, *, history: int = 1, chunk: int = 1, observation_noise: float = 0.0, members: int = 1
) -> PolicyKind:
    """The kind registered as `name`, for a policy of `history` observations and `chunk` actions
    trained with `observation_noise`, of `members` networks; a `ConfigError` on BC's field naming
    what is wrong otherwise."""
    if name not in POLICY_KINDS:
        raise ConfigError(
            "policy", f"must be a registered policy kind ({', '.join(POLICY_KINDS)}), got {name[:40]!r}", owner="BCConfig"
        )
    kind = POLICY_KINDS[name]
    sequential = [field for field, value in (("history", history), ("chunk", chunk)) if value != 1]
    sequential += ["observation_noise"] if observation_noise else []
    if sequential and not kind.sequences:
        sequence_kinds = ", ".join(other.name for other in POLICY_KINDS.values() if other.sequences)
        raise ConfigError(
            sequential[0],
            f"is for sequence policies ({sequence_kinds}); the {name} policy reads one observation and predicts one action",
            owner="BCConfig",
        )
    if members != 1 and not kind.ensembles:
        ensemble_kinds = ", ".join(other.name for other in POLICY_KINDS.values() if other.ensembles)
        raise ConfigError("members", f"is for {ensemble_kinds} policies; the {name} policy is one network", owner="BCConfig")
    return kind


def build_policy(kind: str, observation_space: gym.Space, action_space: gym.Space, **options: Any) -> ImitationPolicy:
    """A fresh policy of `kind` for these spaces, with `PolicyConfig`'s `options`."""
    config = PolicyConfig(
        kind=kind, observation_space=space_to_json(observation_space), action_space=space_to_json(action_space), **options
    )
    return policy_kind(kind).build(config)


def load_policy(path: str | os.PathLike) -> ImitationPolicy:
    """The policy of a run directory (PPO, BC, DAgger, …), of the kind its config names, on the
    CPU, in eval mode."""
    config, weights = read_run(path)
    if "policy" not in config:
        raise ImitationError(f"{path}: a {str(config.get('kind', 'unknown'))[:40]!r} run holds no policy")
    state = {name[len(POLICY_PREFIX) :]: tensor for name, tensor in weights.items() if name.startswith(POLICY_PREFIX)}
    try:
        policy_config = PolicyConfig.from_json(config["policy"])
        if policy_config.kind not in POLICY_KINDS:
            raise ImitationError(
                f"{path}: the policy is of kind {policy_config.kind[:40]!r}, which is not registered here "
                f"(known: {', '.join(POLICY_KINDS)})"
            )
        kind = POLICY_KINDS[policy_config.kind]
        check_weights_cover(path, kind.planned_weights(policy_config), state)
        policy = kind.build(policy_config)
        policy.load_state_dict(state)
    except SpaceError as error:
        raise ImitationError(f"{path}: the policy's {error}") from None
    except (TypeError, KeyError, RuntimeError, ValueError) as error:
        raise ImitationError(
            f"{path}: policy weights do not match its config ({(str(error).splitlines() or [''])[0][:200]})"
        ) from None
    return policy.eval()
