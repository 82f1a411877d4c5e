"""Claim (a) of the notes (§3): a baseline reduces the variance of the policy-gradient estimate
without biasing it.

At fixed policy parameters θ on CartPole-v1, this script draws many independent batches of
episodes and computes, on each batch, the gradient estimate ĝ of every estimator of
`imitation.algorithms.policy_gradient` (the same episodes for all of them):

- "return": w_t = R(τ); "reward-to-go": w_t = G_t; "baseline": w_t = G_t − V_φ(s_t);
- "actor-critic", TD(0) (n = 1) and GAE(λ = 0.95): w_t = Â_t from the same critic V_φ.

with γ = 1 (CartPole's objective, so that R(τ) and G_t estimate the same gradient) and no
normalisation of w_t. θ is a policy part-trained by REINFORCE (so that episodes are neither
trivially short nor capped at 500), and V_φ is fit to that policy's returns by regression on
separate episodes before the measurement, then frozen.

For each estimator it reports, over B batches:

- the total variance of ĝ, tr Cov(ĝ) (the sum of the per-parameter variances);
- its bias against a reference gradient g_ref, the mean of "reward-to-go" over R further
  independent batches: the statistic z = ‖mean ĝ − g_ref‖² / (tr Cov(ĝ)/B + tr Cov_ref/R), whose
  expectation is about 1 for an unbiased estimator (both means are of independent samples) and
  grows with B for a biased one;
- the cosine between mean ĝ and g_ref.

Verdict: the claim holds here when "baseline" has a lower total variance than "reward-to-go"
and "return", and its z stays below 3 (unbiased within noise; a biased estimator's z is far above).

Usage: python bench/claim_baseline_variance.py [--batches 200] [--seed 0]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np
import torch

BENCH = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCH.parent))  # run from a checkout without installing the package

from imitation.algorithms.policy_gradient import PGConfig, PolicyGradient  # noqa: E402
from imitation.seeding import seed_everything  # noqa: E402

ENV_ID = "CartPole-v1"
BATCH_STEPS = 1000
ESTIMATORS = {  # name: (estimator, n_step, gae_lambda)
    "return": ("return", None, 0.95),
    "reward-to-go": ("reward-to-go", None, 0.95),
    "baseline": ("baseline", None, 0.95),
    "actor-critic TD(0)": ("actor-critic", 1, 0.95),
    "actor-critic GAE(0.95)": ("actor-critic", None, 0.95),
}


def prepared_learner(seed: int, pretrain_batches: int, critic_batches: int) -> PolicyGradient:
    """θ part-trained with REINFORCE, then V_φ fit to π_θ's returns with θ held fixed."""
    seed_everything(seed)
    config = PGConfig(
        env_id=ENV_ID, estimator="reward-to-go", gamma=1.0, batch_steps=BATCH_STEPS, learning_rate=1e-2,
        normalize_advantages=True, anneal_lr=False, total_steps=10**9, hidden_sizes=[32, 32], seed=seed,
    )  # fmt: skip
    learner = PolicyGradient(config)
    for _ in range(pretrain_batches):
        learner.step()
    learner.config = dataclasses.replace(config, estimator="baseline", value_learning_rate=3e-3, value_steps=50)
    for _ in range(critic_batches):
        batch = learner.collect()
        _, targets, _ = learner.weights(batch)
        for _ in range(learner.config.value_steps):
            fit = 0.5 * ((learner.policy.value(batch.features) - targets) ** 2).mean()
            learner.value_optimizer.zero_grad(set_to_none=True)
            fit.backward()
            learner.value_optimizer.step()
    learner.config = dataclasses.replace(learner.config, normalize_advantages=False)
    return learner


def gradient(learner: PolicyGradient, batch, name: str) -> np.ndarray:
    estimator, n_step, gae_lambda = ESTIMATORS[name]
    learner.config = dataclasses.replace(learner.config, estimator=estimator, n_step=n_step, gae_lambda=gae_lambda)
    weights, _, _ = learner.weights(batch)
    loss, _ = learner.policy_loss(batch, weights)
    grads = torch.autograd.grad(loss, learner.actor_parameters)
    return -torch.cat([g.reshape(-1) for g in grads]).numpy()  # ĝ ascends J; the loss is −ĝ's surrogate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--batches", type=int, default=200, help="batches per estimator, B (default: 200)")
    parser.add_argument("--reference-batches", type=int, default=400, help="batches of the reference, R (default: 400)")
    parser.add_argument("--seed", type=int, default=0, help="seed (default: 0)")
    args = parser.parse_args()
    started = time.perf_counter()
    torch.set_num_threads(1)
    learner = prepared_learner(args.seed, pretrain_batches=8, critic_batches=30)
    returns: list[float] = []
    estimates: dict[str, list[np.ndarray]] = {name: [] for name in ESTIMATORS}
    for _ in range(args.batches):
        batch = learner.collect()
        returns.extend(batch.episode_returns)
        for name in ESTIMATORS:
            estimates[name].append(gradient(learner, batch, name))
    reference_samples = np.array([gradient(learner, learner.collect(), "reward-to-go") for _ in range(args.reference_batches)])
    reference = reference_samples.mean(axis=0)
    reference_noise = reference_samples.var(axis=0, ddof=1).sum() / args.reference_batches
    print(
        f"{ENV_ID}, fixed θ (mean episode return {np.mean(returns):.1f}, {len(returns)} episodes), B = {args.batches} "
        f"batches of ≥ {BATCH_STEPS} steps, R = {args.reference_batches} reference batches, "
        f"‖g_ref‖ = {np.linalg.norm(reference):.2f}\n"
    )
    print("| estimator | tr Cov(ĝ) | relative to reward-to-go | z (≈ 1 if unbiased) | cos(mean ĝ, g_ref) |")
    print("|---|---:|---:|---:|---:|")
    table = {}
    for name, samples in estimates.items():
        stacked = np.array(samples)
        mean = stacked.mean(axis=0)
        variance = stacked.var(axis=0, ddof=1).sum()
        z = float(np.sum((mean - reference) ** 2) / (variance / args.batches + reference_noise))
        cosine = float(mean @ reference / (np.linalg.norm(mean) * np.linalg.norm(reference)))
        table[name] = (variance, z, cosine)
    for name, (variance, z, cosine) in table.items():
        print(f"| {name} | {variance:.4g} | {variance / table['reward-to-go'][0]:.3f} | {z:.2f} | {cosine:.3f} |")
    baseline_variance, baseline_z, _ = table["baseline"]
    holds = baseline_variance < table["reward-to-go"][0] and baseline_variance < table["return"][0] and baseline_z < 3
    print(
        f"\nverdict (a): {'holds' if holds else 'does not hold here'}: the baseline's variance is "
        f"{baseline_variance / table['reward-to-go'][0]:.2f}× reward-to-go's and {baseline_variance / table['return'][0]:.2f}× "
        f"the whole return's, with z = {baseline_z:.2f}"
    )
    print(f"total runtime: {time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    main()
