"""Gradient-free policy search (docs/THEORY.md §1): hill climbing, the cross-entropy method and
CMA-ES over the parameters θ ∈ ℝ^d of a deterministic policy's actor.

The objective is a black box: Ĵ(θ) = the mean undiscounted return of E episodes of the policy
whose actor (trunk and action head of an `ActorCritic`, linear or MLP; the critic is unused)
holds θ and acts by the mode of π_θ(·|s) (argmax of the logits, the Gaussian's mean). One step of
the learner is one generation: the centre of the search (the incumbent, the mean) and K
candidates are scored on the same E episode starts (common random numbers, so that a candidate
beats the centre by its parameters, not by an easier start), every candidate's episodes running
side by side in a gymnasium vector env. The budget is env steps.

- Hill climbing (§1.1), K perturbations per generation:

      θ'_k = θ + σ ε_k,  ε_k ∼ N(0, I);      θ ← argmax_k Ĵ(θ'_k)  if  max_k Ĵ(θ'_k) > Ĵ(θ)

  Ĵ(θ) is re-evaluated every generation (a lucky score of the incumbent is not kept). The noise
  scale adapts: σ ← clamp(σ · c_success) after an improvement, σ ← clamp(σ · c_failure) after
  none, clamped to [σ_min, σ_max]. The defaults c_success = 1/2, c_failure = 2 are adaptive noise
  scaling (search closer around a new incumbent, wider once the neighbourhood is exhausted);
  c_success > 1 > c_failure gives the (1+1)-ES's success rule of the notes instead.

- The cross-entropy method (§1.2), a diagonal Gaussian N(μ, diag σ²):

      θ_i ∼ N(μ, diag σ²), i = 1 … K;       E = the ⌈ρK⌉ θ_i of highest Ĵ
      μ ← (1/|E|) Σ_{i∈E} θ_i;              σ² ← (1/|E|) Σ_{i∈E} (θ_i − μ)² + Z_t

  with Szita & Lőrincz's (2006) decreasing extra noise Z_t = z₀ · max(1 − t/t_Z, 0) at
  generation t, which keeps the distribution from collapsing before the elites agree.

- CMA-ES (Hansen & Ostermeier 2001): full covariance and global step size adapted by the
  maintained `cma` library (ask/tell; it minimises, so it is told −Ĵ).

What the run keeps is the centre: the incumbent of hill climbing, the mean μ of CEM and CMA-ES.
The best single candidate's score is the maximum of K noisy estimates and so biased upwards
(the winner's curse); the mean is what the search converges to and is scored afresh each
generation, so its logged return is an unbiased estimate of the policy saved.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import cma
import gymnasium as gym
import numpy as np
import torch
from torch import nn

from imitation.algorithms.policy_search_config import NAMES, SearchConfig
from imitation.checkpoints import CheckpointData, CheckpointReader, CheckpointWriter, TrainingClock
from imitation.envs.vector import make_vector_env
from imitation.errors import ConfigError, ImitationError
from imitation.policies import ActorCritic, make_policy, require_flat_observations

# ------------------------------------------------------------------------------------------------
# The formulas, as pure functions (tested against values worked by hand).


def elite_indices(scores: np.ndarray, fraction: float) -> np.ndarray:
    """The ⌈ρK⌉ highest scores' indices, best first (ties: the earlier candidate first)."""
    count = max(1, math.ceil(fraction * len(scores) - 1e-9))  # ⌈ρK⌉, without 0.28 · 25 = 7.000000000000001 → 8
    return np.argsort(-scores, kind="stable")[:count]


def cem_refit(
    samples: np.ndarray, scores: np.ndarray, fraction: float, extra_variance: float
) -> tuple[np.ndarray, np.ndarray]:
    """CEM's update: μ = the elites' mean, σ² = their (population) variance per coordinate + Z."""
    elites = samples[elite_indices(scores, fraction)]
    mean = elites.mean(axis=0)
    return mean, ((elites - mean) ** 2).mean(axis=0) + extra_variance


def extra_variance(generation: int, initial: float, generations: int) -> float:
    """Szita & Lőrincz's decreasing noise Z_t = z₀ · max(1 − t/t_Z, 0)."""
    return initial * max(1.0 - generation / generations, 0.0)


def hill_climb_choice(incumbent_score: float, scores: np.ndarray) -> int | None:
    """The candidate that replaces the incumbent: the best, if strictly better; else None."""
    best = int(np.argmax(scores))
    return best if scores[best] > incumbent_score else None


def adapt_sigma(sigma: float, improved: bool, config: SearchConfig) -> float:
    """σ · c_success after an improvement, σ · c_failure otherwise, clamped to [σ_min, σ_max]."""
    scaled = sigma * (config.success_factor if improved else config.failure_factor)
    return min(max(scaled, config.sigma_min), config.sigma_max)


# ------------------------------------------------------------------------------------------------
# The searched vector: the actor's parameters


def actor_parameters(policy: ActorCritic) -> list[nn.Parameter]:
    """The actor's trunk and action head, in the order parameters_to_vector flattens them."""
    return [*policy.actor_trunk.parameters(), *policy.action_head.parameters()]


def actor_vector(policy: ActorCritic) -> np.ndarray:
    return nn.utils.parameters_to_vector(actor_parameters(policy)).detach().cpu().double().numpy()


def load_actor_vector(policy: ActorCritic, vector: np.ndarray) -> None:
    with torch.no_grad():
        nn.utils.vector_to_parameters(torch.as_tensor(vector, dtype=torch.float32), actor_parameters(policy))


def actor_outputs(policy: ActorCritic, vectors: torch.Tensor, features: torch.Tensor) -> torch.Tensor:
    """The action head's output for row b of `features` by the actor whose parameters are row b
    of `vectors` (B, d): one batched pass for B different policies, the layers read from the
    vector in parameters_to_vector's order (each Linear's weight, then its bias)."""
    x, offset, batch = features, 0, len(vectors)
    for module in [*policy.actor_trunk, policy.action_head]:
        if isinstance(module, nn.Linear):
            outputs, inputs = module.weight.shape
            weight = vectors[:, offset : offset + outputs * inputs].reshape(batch, outputs, inputs)
            offset += outputs * inputs
            bias = vectors[:, offset : offset + outputs]
            offset += outputs
            x = torch.baddbmm(bias.unsqueeze(-1), weight, x.unsqueeze(-1)).squeeze(-1)
        else:
            x = module(x)
    return x


def mode(policy: ActorCritic, outputs: torch.Tensor) -> torch.Tensor:
    """The mode of π_θ(·|s) from the action head's output: the Gaussian's mean, or the argmax of
    the logits (of each component's, for MultiDiscrete actions). Written out: building a
    torch distribution per step costs more than these small networks."""
    if policy.is_continuous:
        return outputs
    if policy.action_sizes is not None:
        return torch.stack([part.argmax(-1) for part in torch.split(outputs, policy.action_sizes, dim=-1)], -1)
    return outputs.argmax(-1)


# ------------------------------------------------------------------------------------------------
# The three searches: each proposes a generation's centre and candidates and learns from their scores.


class HillClimbing:
    """The incumbent θ and the noise scale σ."""

    def __init__(self, config: SearchConfig, start: np.ndarray) -> None:
        self.config = config
        self.theta = start.copy()
        self.sigma = config.sigma

    def propose(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        noise = rng.standard_normal((self.config.population, len(self.theta)))
        return self.theta, self.theta + self.sigma * noise

    def tell(self, candidates: np.ndarray, centre_score: float, scores: np.ndarray) -> dict[str, float]:
        choice = hill_climb_choice(centre_score, scores)
        if choice is not None:
            self.theta = candidates[choice].copy()
        self.sigma = adapt_sigma(self.sigma, choice is not None, self.config)
        return {"sigma": self.sigma, "improved": float(choice is not None)}

    def centre(self) -> np.ndarray:
        return self.theta

    def state(self) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        return {"search.theta": torch.as_tensor(self.theta)}, {"sigma": self.sigma}

    def restore(self, tensors: dict[str, torch.Tensor], state: dict[str, Any]) -> None:
        self.theta = _vector(tensors["search.theta"], len(self.theta))
        self.sigma = float(state["sigma"])


class CrossEntropy:
    """The search distribution N(μ, diag σ²) and the generation t of its extra variance."""

    def __init__(self, config: SearchConfig, start: np.ndarray) -> None:
        self.config = config
        self.mean = start.copy()
        self.variance = np.full_like(start, config.sigma**2)
        self.generation = 0

    def propose(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        noise = rng.standard_normal((self.config.population, len(self.mean)))
        return self.mean, self.mean + np.sqrt(self.variance) * noise

    def tell(self, candidates: np.ndarray, centre_score: float, scores: np.ndarray) -> dict[str, float]:
        config = self.config
        extra = extra_variance(self.generation, config.extra_noise, config.extra_noise_generations)
        self.mean, self.variance = cem_refit(candidates, scores, config.elite_fraction, extra)
        self.generation += 1
        return {"sigma": float(np.sqrt(self.variance).mean()), "extra_noise": extra}

    def centre(self) -> np.ndarray:
        return self.mean

    def state(self) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        tensors = {"search.mean": torch.as_tensor(self.mean), "search.variance": torch.as_tensor(self.variance)}
        return tensors, {"generation": self.generation}

    def restore(self, tensors: dict[str, torch.Tensor], state: dict[str, Any]) -> None:
        self.mean = _vector(tensors["search.mean"], len(self.mean))
        self.variance = _vector(tensors["search.variance"], len(self.mean))
        self.generation = int(state["generation"])


class CMAES:
    """`cma`'s CMAEvolutionStrategy, sampling from its own generator. Its state is not saved
    (pickle is the only way `cma` offers): a checkpoint keeps the −Ĵ it was told each
    generation, and `restore` rebuilds the strategy from the start point and seed and replays
    ask/tell with them, which reproduces its mean, step size and covariance exactly."""

    def __init__(self, config: SearchConfig, start: np.ndarray) -> None:
        self.config = config
        self.start = start.copy()
        self.told: list[list[float]] = []
        self.es = self._strategy()

    def _strategy(self) -> cma.CMAEvolutionStrategy:
        generator = np.random.default_rng([self.config.seed, 0x434D41])

        def randn(*shape: int) -> np.ndarray:
            return generator.standard_normal(shape)

        options = {"popsize": self.config.population, "randn": randn, "verbose": -9, "verb_log": 0, "verb_disp": 0}
        return cma.CMAEvolutionStrategy(self.start, self.config.sigma, options)

    def propose(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        return self.es.mean.copy(), np.asarray(self.es.ask())

    def tell(self, candidates: np.ndarray, centre_score: float, scores: np.ndarray) -> dict[str, float]:
        losses = [-float(score) for score in scores]
        self.es.tell(list(candidates), losses)
        self.told.append(losses)
        return {"sigma": float(self.es.sigma)}

    def centre(self) -> np.ndarray:
        return np.asarray(self.es.mean)

    def state(self) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        return {}, {"told": self.told}

    def restore(self, tensors: dict[str, torch.Tensor], state: dict[str, Any]) -> None:
        self.es, self.told = self._strategy(), []
        for losses in state["told"]:
            if len(losses) != self.config.population:
                raise ValueError(f"a generation of {len(losses)} scores, not {self.config.population}")
            self.es.tell(self.es.ask(), [float(loss) for loss in losses])
            self.told.append([float(loss) for loss in losses])


def _vector(tensor: torch.Tensor, size: int) -> np.ndarray:
    if tensor.shape != (size,):
        raise ValueError(f"a parameter vector of shape {tuple(tensor.shape)}, not ({size},)")
    return tensor.double().numpy().copy()


STRATEGIES: dict[str, type[HillClimbing] | type[CrossEntropy] | type[CMAES]] = {
    "hill-climb": HillClimbing,
    "cem": CrossEntropy,
    "cmaes": CMAES,
}


# ------------------------------------------------------------------------------------------------
# The learner


class PolicySearch:
    """A search's state (its strategy, the policy whose actor is the centre, counters) and its
    step, one generation. Everything random in generation t comes from a generator seeded by
    (seed, t), CMA-ES's sampling from its own seeded one: a resumed run repeats the generations an
    uninterrupted one would have run. The environments are not part of the checkpoint; each
    generation resets them to its own episode seeds."""

    unit = "generation"

    def __init__(self, config: SearchConfig) -> None:
        config.validate()
        torch.set_num_threads(config.threads)
        torch.manual_seed(config.seed)
        self.config = config
        self.name = NAMES[config.method]
        envs = make_vector_env(config.env_id, config.n_envs, vectorised=False)
        assert isinstance(envs, gym.vector.SyncVectorEnv)  # resets copies one by one, each to its episode's seed
        self.envs = envs
        self.policy = require_flat_observations(
            make_policy(
                self.envs.single_observation_space,
                self.envs.single_action_space,
                hidden_sizes=list(config.hidden_sizes),
                activation=config.activation,
            ),
            "policy search",
        )
        self.policy.eval()
        self.search = STRATEGIES[config.method](config, actor_vector(self.policy))
        self.dimension = len(self.search.centre())
        spec = self.envs.get_attr("spec")[0]
        self.episode_limit: int | None = spec.max_episode_steps if spec is not None else None
        # The most env steps one generation can take (None: episodes without a time limit).
        cost = (config.population + 1) * config.episodes_per_candidate
        self.generation_limit = cost * self.episode_limit if self.episode_limit else None
        if self.generation_limit is not None and config.total_steps < self.generation_limit:
            raise ConfigError(
                "total_steps",
                f"{config.total_steps} is less than one generation at full episode length ({config.population + 1} "
                f"policies × {config.episodes_per_candidate} episodes × {self.episode_limit} steps)",
                owner="SearchConfig",
            )
        self.generations = 0
        self.global_step = 0
        self.episodes = 0
        self.clock = TrainingClock()
        self.total = self._projected_total()
        load_actor_vector(self.policy, self.search.centre())

    def _projected_total(self) -> int:
        """The generations the budget is projected to last, at the mean cost of those so far
        (before the first, at full episode length): refined after each generation."""
        if self.done:
            return self.generations
        left = self.config.total_steps - self.global_step - (self.generation_limit or 0)
        # left / (global_step / generations) in integers: the float quotient floored one short
        # where it was a whole number (8,490 · 3 / 10 = 2,551 came out 2,550).
        more = left * self.generations // self.global_step if self.generations else left // (self.generation_limit or 1)
        return self.generations + max(0, more) + 1

    @property
    def completed(self) -> int:
        return self.generations

    @property
    def done(self) -> bool:
        """No generation is started that could pass the budget at full episode length."""
        reserve = self.generation_limit or 1
        return self.global_step + reserve > self.config.total_steps

    def position(self) -> str:
        return f"generation {self.generations}, at step {self.global_step} of {self.config.total_steps}"

    def progress(self, row: dict[str, float]) -> dict[str, str]:
        return {"ret": f"{row['return']:.1f}", "best": f"{row['best_return']:.1f}", "step": f"{row['step']:.0f}"}

    def step(self) -> dict[str, float]:
        """One generation: the centre and K candidates scored on E shared episode starts, then
        the strategy's update."""
        self.clock.start()
        config = self.config
        rng = np.random.default_rng([config.seed, self.generations])
        centre, candidates = self.search.propose(rng)
        seeds = [int(seed) for seed in rng.integers(0, 2**31 - 1, config.episodes_per_candidate)]
        scores = self.evaluate(np.vstack([centre[None], candidates]), seeds)
        centre_score, candidate_scores = float(scores[0]), scores[1:]
        update = self.search.tell(candidates, centre_score, candidate_scores)
        load_actor_vector(self.policy, self.search.centre())
        self.generations += 1
        self.total = self._projected_total()
        return {
            "step": float(self.global_step),
            "generation": float(self.generations),
            "return": centre_score,
            "population_return": float(candidate_scores.mean()),
            "best_return": float(candidate_scores.max()),
            "episodes": float(self.episodes),
            "steps_per_second": self.global_step / self.clock.seconds,
            **update,
        }

    def evaluate(self, vectors: np.ndarray, seeds: Sequence[int]) -> np.ndarray:
        """Ĵ of each row of `vectors`: its mean return over the episodes started from `seeds`,
        the (policy, episode) pairs dealt to the vector env's copies as they come free."""
        config, envs = self.config, self.envs
        jobs = [(candidate, seed) for candidate in range(len(vectors)) for seed in seeds]
        returns = np.zeros((len(vectors), len(seeds)))
        parameters = torch.as_tensor(vectors, dtype=torch.float32)
        slot_job = np.full(config.n_envs, -1)
        dealt = min(len(jobs), config.n_envs)
        slot_job[:dealt] = np.arange(dealt)
        # Idle copies (fewer jobs than copies) step along with seed 0; nothing of theirs is kept.
        observations, _ = envs.reset(seed=[jobs[j][1] if j >= 0 else 0 for j in slot_job])
        self._check_finite(observation=observations)
        while (slot_job >= 0).any():
            active = slot_job >= 0
            rows = parameters[np.array([jobs[j][0] if j >= 0 else 0 for j in slot_job])]
            with torch.no_grad():
                features = self.policy.encode(torch.as_tensor(observations))
                actions = self.policy.to_env_action(mode(self.policy, actor_outputs(self.policy, rows, features)))
            observations, rewards, terminated, truncated, _ = envs.step(actions)
            self._check_finite(observation=observations[active], reward=np.asarray(rewards)[active])
            self.global_step += int(active.sum())
            for slot in np.flatnonzero(active):
                job = slot_job[slot]
                returns[jobs[job][0], job % len(seeds)] += rewards[slot]
            ended = np.flatnonzero(active & (terminated | truncated))
            if ended.size == 0:
                continue
            self.episodes += ended.size
            restart = np.zeros(config.n_envs, dtype=bool)
            for slot in ended:
                if dealt < len(jobs):
                    slot_job[slot], restart[slot] = dealt, True
                    dealt += 1
                else:
                    slot_job[slot] = -1
            if restart.any():
                episode_seeds = [jobs[slot_job[slot]][1] if restart[slot] else None for slot in range(config.n_envs)]
                observations, _ = envs.reset(seed=episode_seeds, options={"reset_mask": restart})
                self._check_finite(observation=observations[restart])
        return returns.mean(axis=1)

    def _check_finite(self, **values: np.ndarray) -> None:
        """A NaN or ±inf from the environment would make every comparison of scores meaningless."""
        for what, array in values.items():
            if array.dtype.kind == "f" and not np.isfinite(array).all():
                raise ImitationError(
                    f"{self.config.env_id}: the environment returned a non-finite {what} by env step {self.global_step} "
                    f"(generation {self.generations + 1}); {self.name} needs finite observations and rewards"
                )

    def close(self) -> None:
        self.envs.close()

    def state_dict(self) -> CheckpointData:
        tensors, search_state = self.search.state()
        checkpoint = CheckpointWriter(
            generation=self.generations, global_step=self.global_step, episodes=self.episodes, search=search_state
        )
        checkpoint.clock(self.clock)
        checkpoint.tensors |= tensors
        return checkpoint.data()

    def load_state_dict(self, checkpoint: CheckpointData) -> None:
        with CheckpointReader(checkpoint, self.name) as saved:
            self.search.restore(saved.tensors, saved.state["search"])
            self.global_step = saved.counter("global_step", "env step", 0, self.config.total_steps)
            self.generations = saved.counter("generation", "next generation", 0, self.global_step)
            self.episodes = int(saved.state["episodes"])
            saved.clock(self.clock)
            self.total = self._projected_total()
            load_actor_vector(self.policy, self.search.centre())
