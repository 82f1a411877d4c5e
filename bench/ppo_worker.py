"""One measurement for bench/ppo.py, run in a process of its own.

    python bench/ppo_worker.py {ours,sb3,floors} SPEC.json RESULT.json

`ours` trains with imitation's PPO learner (run in the shared loop), `sb3` with stable-baselines3's PPO (run it with the
interpreter of bench/.venv-sb3), `floors` times the bare loops that our three parts are compared
with. SPEC holds the rl-baselines3-zoo hyperparameters and the run's settings; both sides
translate the same zoo values here, so the translation and its gaps are in one place.

Only the standard library is imported at module level: bench/ppo.py imports this file for the
translation, and the SB3 venv has no `imitation` while the main venv has no SB3.
"""

from __future__ import annotations

import json
import math
import sys
import time
from typing import Any, Callable

# Zoo hyperparameter values such as "lin_0.001" mean "linear from 0.001 down to 0".
LINEAR_PREFIX = "lin_"


def parse_zoo_value(value: float | str) -> tuple[float, bool]:
    """(initial value, linearly annealed to 0?) of a zoo float or "lin_X" entry."""
    if isinstance(value, str) and value.startswith(LINEAR_PREFIX):
        return float(value[len(LINEAR_PREFIX) :]), True
    return float(value), False


def ours_config_kwargs(zoo: dict[str, Any]) -> tuple[dict[str, Any], list[str]]:
    """PPOConfig keyword arguments for the zoo settings, and what PPOConfig cannot express.

    Everything the zoo leaves at SB3's default is set to that default explicitly, so that no
    value of ours (e.g. the presets' observation normalisation for Pendulum) differs silently."""
    learning_rate, anneal_lr = parse_zoo_value(zoo["learning_rate"])
    clip_range, clip_annealed = parse_zoo_value(zoo["clip_range"])
    gaps = []
    if clip_annealed:
        gaps.append(f"clip_range {zoo['clip_range']} (linear) runs as a constant {clip_range} in ours")
    if zoo.get("use_sde"):
        gaps.append(
            f"use_sde=True, sde_sample_freq={zoo.get('sde_sample_freq', -1)} (gSDE exploration) runs as a plain "
            "Gaussian with a state-independent log-std in ours"
        )
    kwargs = dict(
        n_envs=zoo["n_envs"],
        n_steps=zoo["n_steps"],
        batch_size=zoo["batch_size"],
        n_epochs=zoo["n_epochs"],
        gamma=zoo["gamma"],
        gae_lambda=zoo["gae_lambda"],
        learning_rate=learning_rate,
        anneal_lr=anneal_lr,
        clip_range=clip_range,
        entropy_coef=zoo["ent_coef"],
        # SB3's defaults, which the zoo entries leave alone:
        value_coef=0.5,
        max_grad_norm=0.5,
        clip_value_loss=False,
        target_kl=None,
        normalize_advantages=True,
        normalize_observations=False,
        normalize_rewards=False,
        hidden_sizes=[64, 64],
        activation="tanh",
        shared_trunk=False,
        log_std_init=0.0,
    )
    return kwargs, gaps


def sb3_kwargs(zoo: dict[str, Any]) -> dict[str, Any]:
    """stable-baselines3 PPO keyword arguments for the zoo settings (schedules as callables)."""

    def schedule(value: float | str) -> float | Callable[[float], float]:
        initial, linear = parse_zoo_value(value)
        # SB3 calls schedules with progress_remaining, which falls from 1 to 0.
        return (lambda progress_remaining: progress_remaining * initial) if linear else initial

    kwargs = {key: value for key, value in zoo.items() if key not in ("n_envs", "learning_rate", "clip_range")}
    kwargs["learning_rate"] = schedule(zoo["learning_rate"])
    kwargs["clip_range"] = schedule(zoo["clip_range"])
    return kwargs


def rollout_count(spec: dict[str, Any]) -> int:
    """Updates that both trainers run to reach at least total_steps (each rounds up)."""
    zoo = spec["zoo"]
    return -(-spec["total_steps"] // (zoo["n_envs"] * zoo["n_steps"]))


# ------------------------------------------------------------------------------------------------
# Trainers. Both clocks start just before the vector env and model are built (imports excluded)
# and record a mark (seconds, env steps, mean return of the last `window` episodes) after every
# update; bench/ppo.py finds the time to target in the marks.
#
# _PREIMPORT: the first torch.optim.Adam() of a process imports torch._dynamo (about 1 s here);
# SB3's trainer imports it before its clock starts, as that is start-up, not training. Ours
# builds no torch.optim optimiser (imitation.flat_adam), so it has nothing to import early.


def run_ours(spec: dict[str, Any]) -> dict[str, Any]:
    """Train with imitation's PPO; marks from the per-update log rows."""
    from imitation.algorithms.ppo import PPO, PPOConfig
    from imitation.jobs.loop import run

    kwargs, _ = ours_config_kwargs(spec["zoo"])
    config = PPOConfig(
        env_id=spec["env_id"], total_steps=spec["total_steps"], seed=spec["seed"], device="cpu", threads=spec["threads"], **kwargs
    )
    marks: list[list[float]] = []
    started = time.perf_counter()
    ppo = PPO(config)  # builds the vector env and the model: inside the clock, as SB3's side
    try:
        rows = run(ppo, log=lambda row: marks.append([time.perf_counter() - started, row["step"], row["return"]]))
        seconds = time.perf_counter() - started
    finally:
        ppo.close()
    last = rows[-1]
    return {
        "seconds": seconds,
        "steps": ppo.global_step,
        "steps_per_second": ppo.global_step / seconds,
        "final_return": last["return"],
        "seconds_env": last["seconds_env"],
        "seconds_inference": last["seconds_inference"],
        "seconds_update": last["seconds_update"],
        "marks": marks,
    }


def run_sb3(spec: dict[str, Any]) -> dict[str, Any]:
    """Train with stable-baselines3's PPO; marks from a callback reading ep_info_buffer."""
    import numpy as np
    import torch
    import torch._dynamo  # noqa: F401  (see _PREIMPORT)
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.env_util import make_vec_env

    # SB3 leaves torch's thread count alone; the benchmark runs both sides on the same count.
    torch.set_num_threads(spec["threads"])
    window = spec["window"]

    class Watch(BaseCallback):
        """Marks each update's end (= the next rollout's start, or training's end) like ours does,
        and splits SB3's time into rollouts (env, inference, GAE) and updates (train, logging)."""

        def __init__(self, started: float) -> None:
            super().__init__()
            self.started = started
            self.marks: list[list[float]] = []
            self.rollout_started = started
            self.rollout_ended: float | None = None
            self.pending_return = math.nan
            self.rollout_seconds = 0.0
            self.update_seconds = 0.0

        def _on_step(self) -> bool:
            return True

        def _mark_update_end(self) -> None:
            now = time.perf_counter()
            if self.rollout_ended is not None:
                self.update_seconds += now - self.rollout_ended
                self.marks.append([now - self.started, float(self.num_timesteps), self.pending_return])
                self.rollout_ended = None
            self.rollout_started = now

        def _on_rollout_start(self) -> None:
            self._mark_update_end()

        def _on_rollout_end(self) -> None:
            self.rollout_ended = time.perf_counter()
            self.rollout_seconds += self.rollout_ended - self.rollout_started
            recent = [info["r"] for info in list(self.model.ep_info_buffer)[-window:]]
            self.pending_return = float(np.mean(recent)) if recent else math.nan

        def _on_training_end(self) -> None:
            self._mark_update_end()

    zoo = spec["zoo"]
    started = time.perf_counter()
    env = make_vec_env(spec["env_id"], n_envs=zoo["n_envs"], seed=spec["seed"])
    model = PPO("MlpPolicy", env, seed=spec["seed"], device="cpu", verbose=0, **sb3_kwargs(zoo))
    watch = Watch(started)
    model.learn(total_timesteps=spec["total_steps"], callback=watch)
    seconds = time.perf_counter() - started
    env.close()
    return {
        "seconds": seconds,
        "steps": int(model.num_timesteps),
        "steps_per_second": model.num_timesteps / seconds,
        "final_return": watch.marks[-1][2] if watch.marks else math.nan,
        "seconds_rollout": watch.rollout_seconds,
        "seconds_update": watch.update_seconds,
        "marks": watch.marks,
    }


# ------------------------------------------------------------------------------------------------
# Floors: the least each of our three parts could cost for the same amount of work.


def _mlp(torch: Any, inputs: int, outputs: int) -> Any:
    """SB3's and our MlpPolicy trunk plus head: inputs → 64 → 64 → outputs, tanh."""
    nn = torch.nn
    return nn.Sequential(nn.Linear(inputs, 64), nn.Tanh(), nn.Linear(64, 64), nn.Tanh(), nn.Linear(64, outputs))


def floor_env(spec: dict[str, Any], vector_steps: int) -> float:
    """Seconds to step our very vector env (same factory, same-step autoreset, episode
    statistics) `vector_steps` times with actions drawn beforehand."""
    import gymnasium as gym
    import numpy as np

    from imitation.envs.vector import make_vector_env

    envs = make_vector_env(spec["env_id"], spec["zoo"]["n_envs"])
    rng = np.random.default_rng(spec["seed"])
    space = envs.single_action_space
    n_envs = spec["zoo"]["n_envs"]
    if isinstance(space, gym.spaces.Discrete):
        actions = rng.integers(space.start, space.start + space.n, size=(vector_steps, n_envs))
    else:
        actions = rng.uniform(space.low, space.high, size=(vector_steps, n_envs, *space.shape)).astype(space.dtype)
    envs.reset(seed=spec["seed"])
    started = time.perf_counter()
    for action in actions:
        envs.step(action)
    seconds = time.perf_counter() - started
    envs.close()
    return seconds


def _network_shapes(env_id: str) -> tuple[int, int, bool]:
    """(observation size, actor outputs, continuous?) of env_id's spaces."""
    import gymnasium as gym
    import numpy as np

    env = gym.make(env_id)
    obs_size = int(np.prod(env.observation_space.shape))
    space = env.action_space
    env.close()
    if isinstance(space, gym.spaces.Discrete):
        return obs_size, int(space.n), False
    return obs_size, int(np.prod(space.shape)), True


def floor_inference(spec: dict[str, Any], vector_steps: int) -> float:
    """Seconds for `vector_steps` no-grad forward passes of actor and critic on n_envs observations."""
    import torch

    obs_size, actor_outputs, _ = _network_shapes(spec["env_id"])
    actor, critic = _mlp(torch, obs_size, actor_outputs), _mlp(torch, obs_size, 1)
    observations = torch.randn(spec["zoo"]["n_envs"], obs_size)
    started = time.perf_counter()
    with torch.no_grad():
        for _ in range(vector_steps):
            actor(observations)
            critic(observations)
    return time.perf_counter() - started


def floor_update(spec: dict[str, Any], gradient_steps: int) -> float:
    """Seconds for `gradient_steps` minibatch steps: gather a random minibatch from a rollout-sized
    buffer, forward actor and critic, a policy-gradient-plus-value loss, backward, and the step of
    the optimiser ours runs (imitation.flat_adam's FlatAdam)."""
    import torch

    from imitation.flat_adam import FlatAdam

    zoo = spec["zoo"]
    obs_size, actor_outputs, continuous = _network_shapes(spec["env_id"])
    actor, critic = _mlp(torch, obs_size, actor_outputs), _mlp(torch, obs_size, 1)
    log_std = torch.nn.Parameter(torch.zeros(actor_outputs))
    parameters = [*actor.parameters(), *critic.parameters()] + ([log_std] if continuous else [])
    optimizer = FlatAdam(parameters, lr=1e-4, eps=1e-5)
    rollout_size = zoo["n_envs"] * zoo["n_steps"]
    observations = torch.randn(rollout_size, obs_size)
    actions = torch.randn(rollout_size, actor_outputs) if continuous else torch.randint(actor_outputs, (rollout_size, 1))
    advantages, returns = torch.randn(rollout_size), torch.randn(rollout_size)
    minibatches_per_epoch = -(-rollout_size // zoo["batch_size"])
    started = time.perf_counter()
    done = 0
    while done < gradient_steps:
        order = torch.randperm(rollout_size)
        for start in range(0, minibatches_per_epoch * zoo["batch_size"], zoo["batch_size"]):
            if done == gradient_steps:
                break
            index = order[start : start + zoo["batch_size"]]
            outputs = actor(observations[index])
            if continuous:
                log_prob = (-0.5 * ((actions[index] - outputs) / log_std.exp()) ** 2 - log_std).sum(-1)
            else:
                log_prob = torch.log_softmax(outputs, -1).gather(1, actions[index]).squeeze(1)
            value = critic(observations[index]).squeeze(1)
            loss = -(log_prob * advantages[index]).mean() + 0.5 * ((value - returns[index]) ** 2).mean()
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            done += 1
    return time.perf_counter() - started


def run_floors(spec: dict[str, Any]) -> dict[str, Any]:
    """The three floors for the work of one training run of spec (same counts as ours does)."""
    import torch

    torch.set_num_threads(spec["threads"])
    zoo = spec["zoo"]
    updates = rollout_count(spec)
    vector_steps = updates * zoo["n_steps"]
    gradient_steps = updates * zoo["n_epochs"] * -(-(zoo["n_envs"] * zoo["n_steps"]) // zoo["batch_size"])
    return {
        "vector_steps": vector_steps,
        "gradient_steps": gradient_steps,
        "seconds_env": floor_env(spec, vector_steps),
        "seconds_inference": floor_inference(spec, vector_steps),
        "seconds_update": floor_update(spec, gradient_steps),
    }


MODES: dict[str, Callable[[dict[str, Any]], dict[str, Any]]] = {"ours": run_ours, "sb3": run_sb3, "floors": run_floors}


def main(argv: list[str]) -> None:
    """Run MODE on SPEC.json and write the result to RESULT.json."""
    if len(argv) != 3 or argv[0] not in MODES:
        sys.exit(f"usage: ppo_worker.py {{{','.join(MODES)}}} SPEC.json RESULT.json")
    mode, spec_path, result_path = argv
    with open(spec_path) as file:
        spec = json.load(file)
    result = MODES[mode](spec)
    with open(result_path, "w") as file:
        json.dump(result, file)


if __name__ == "__main__":
    main(sys.argv[1:])
