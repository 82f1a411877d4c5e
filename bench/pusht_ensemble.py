"""Benchmark: trained PushT diffusion runs acted otherwise than `eval policy` acts them, in the same
episodes (seeds 10000 + i): the denoisers of several runs averaged at each DDIM step (an ensemble of
separately trained runs, each with its own normalisation), and/or K chunks sampled per plan with
one of them executed: the medoid of the K, or the one closest to the previous plan's unexecuted
actions (backward coherence). Prints the mean max coverage, the success rate and the episodes'
max coverages sorted (where it fails), then one JSON line (bench/RESULTS.md, "PushT: what did and
did not move the diffusion head").

    .venv/bin/python bench/pusht_ensemble.py RUN [RUN ...] [--samples K --select medoid|coherence] [--episodes 50]

RUN: a diffusion run directory, e.g. one `python bench/pusht.py --heads diffusion --keep DIR` left in DIR.
"""

from __future__ import annotations

import argparse
import json
import os

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import gym_pusht  # noqa: E402, F401  (registers gym_pusht/PushT-v0)
import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

from imitation.diffusion_policy import DiffusionPolicy  # noqa: E402
from imitation.policy_kinds import load_policy  # noqa: E402

ENV = "gym_pusht/PushT-v0"
EVAL_SEED = 10_000


class Acting:
    """The first run's plans and history, its chunks denoised by the mean of every run's denoiser
    (each reading the history through its own statistics), `samples` of them per plan, one executed."""

    def __init__(self, runs: list[str], samples: int, select: str) -> None:
        self.policies = [load_policy(run) for run in runs]
        if not all(isinstance(policy, DiffusionPolicy) for policy in self.policies):
            raise SystemExit("every RUN must hold a diffusion policy")
        self.lead: DiffusionPolicy = self.policies[0]  # type: ignore[assignment]
        self.samples, self.select = samples, select

    def sample(self, history: torch.Tensor) -> np.ndarray:
        """(batch, samples, H, action) chunks, every run's prediction averaged at each step."""
        lead = self.lead
        history = history.repeat_interleave(self.samples, 0)
        conditions = [policy.observed(history) for policy in self.policies]
        chunk = torch.randn((len(history), lead.config.chunk * lead.action_width), generator=lead.noise)
        for step in lead.sampler.timesteps:
            steps = torch.full((len(chunk),), int(step), dtype=torch.long)
            predicted = torch.stack(
                [policy._predictions(chunk, steps, condition).mean(0) for policy, condition in zip(self.policies, conditions)]
            ).mean(0)
            chunk = lead.sampler.step(predicted, int(step), chunk, eta=float(lead.config.sampling_noise), generator=lead.noise)
            chunk = chunk.prev_sample
        planned = lead._env_actions(chunk.clamp(-1, 1)).numpy()
        return planned.reshape(len(history) // self.samples, self.samples, *planned.shape[1:])

    def choose(self, candidates: np.ndarray, previous: np.ndarray | None, done: int) -> np.ndarray:
        rows = np.arange(len(candidates))
        flat = candidates.reshape(len(candidates), self.samples, -1)
        if self.select == "medoid":
            spread = ((flat[:, :, None] - flat[:, None]) ** 2).sum((-1, -2))
            return candidates[rows, spread.argmin(1)]
        if previous is None:  # an episode's first plan has nothing to continue
            return candidates[:, 0]
        left = previous[:, done:]
        distance = ((candidates[:, :, : left.shape[1]] - left[:, None]) ** 2).reshape(len(candidates), self.samples, -1)
        return candidates[rows, distance.sum(-1).argmin(1)]

    def episode(self, env: gym.Env, seed: int) -> tuple[float, bool]:
        lead = self.lead
        observation, _ = env.reset(seed=seed)
        lead.reset()
        plan, done, best, success = None, 0, 0.0, False
        for _ in range(300):
            if lead._history.push(lead.acting_rows(observation[None])):
                plan = None
            if plan is None or done >= lead.execute:
                with torch.no_grad():
                    candidates = self.sample(torch.as_tensor(lead._history.rows))
                plan, done = self.choose(candidates, plan, done), 0
            action = np.clip(plan[0, done], env.action_space.low, env.action_space.high).astype(np.float32)
            done += 1
            observation, _, terminated, truncated, info = env.step(action)
            best, success = max(best, float(info["coverage"])), success or bool(info["is_success"])
            if terminated or truncated:
                break
        return best, success


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+")
    parser.add_argument("--samples", type=int, default=1, help="chunks sampled per plan (default 1)")
    parser.add_argument("--select", choices=("medoid", "coherence"), default="medoid")
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    acting = Acting(args.runs, args.samples, args.select)
    env = gym.make(ENV)
    scores = [acting.episode(env, EVAL_SEED + i) for i in range(args.episodes)]
    coverage = [best for best, _ in scores]
    result = {
        "runs": args.runs,
        "samples": args.samples,
        "select": args.select if args.samples > 1 else None,
        "mean_max_coverage": float(np.mean(coverage)),
        "success_rate": float(np.mean([success for _, success in scores])),
        "episode_coverage_sorted": sorted(round(value, 3) for value in coverage),
    }
    print(f"mean max coverage {result['mean_max_coverage']:.3f}, success {result['success_rate']:.2f}")
    print(json.dumps(result))


if __name__ == "__main__":
    main()
