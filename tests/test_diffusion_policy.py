"""The diffusion policy kind (imitation/diffusion_policy.py): its noised-chunk loss, DDIM's denoising
and the moving average against values worked by hand; the kind end to end through the command line
on PushT's human demos (convert, train bc, eval policy with coverage) and on the bundled Pendulum
demos, with its one-line refusals."""

from __future__ import annotations

import json
import math
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from support import DATASETS

import cli
from imitation.data.mcap.reader import DemoFile
from imitation.data.windows import WindowBatch
from imitation.diffusion_policy import EMA_POWER, DiffusionPolicy, planned_weights
from imitation.errors import ImitationError
from imitation.policy_kinds import build_policy, load_policy
from imitation.policy_protocol import ImitationObjective, PolicyConfig

OBSERVATION = gym.spaces.Box(-np.inf, np.inf, (1,), np.float32)
ACTION = gym.spaces.Box(-10, 10, (1,), np.float32)
PUSHT = Path("manipulation/pusht/pusht_cchi_v7_replay.zarr")


def _alpha_bars(steps: int) -> np.ndarray:
    """ᾱ_k of the squared-cosine schedule (Nichol and Dhariwal 2021), worked from its definition."""
    f = lambda t: math.cos((t / steps + 0.008) / 1.008 * math.pi / 2) ** 2  # noqa: E731
    betas = [min(1 - f(i + 1) / f(i), 0.999) for i in range(steps)]
    return np.cumprod([1 - beta for beta in betas])


def _linear(
    chunk: int, denoising_steps: int = 100, sampling_steps: int = 10, execute: int | None = None, prediction: str = "noise",
    members: int = 1,
) -> DiffusionPolicy:
    """A diffusion policy whose denoiser is one linear layer (no hidden layer), actions scaled from [0, 4]."""
    policy = build_policy(
        "diffusion", OBSERVATION, ACTION, hidden_sizes=[], chunk=chunk, denoising_steps=denoising_steps, sampling_steps=sampling_steps,
        execute=execute, prediction=prediction, members=members,
    )
    assert isinstance(policy, DiffusionPolicy)
    policy.fit_action_normalizer(torch.tensor([[0.0], [4.0]]), None)
    return policy


@pytest.mark.parametrize("prediction", ["noise", "sample"])
def test_the_loss_is_the_error_of_the_predicted_noise_or_clean_chunk_on_the_noised_chunk(prediction: str) -> None:
    policy = _linear(chunk=2, denoising_steps=4, sampling_steps=2, prediction=prediction)
    with torch.no_grad():  # ε_θ(A^k, k, o) = A^k: the head copies the noisy chunk and ignores the rest
        policy.denoiser.head.weight.zero_()
        policy.denoiser.head.weight[:, :2] = torch.eye(2)
        policy.denoiser.head.bias.zero_()
    actions = torch.tensor([[[1.0], [4.0]], [[2.0], [0.0]]])
    batch = WindowBatch(torch.zeros(2, 1, 1), torch.zeros(2, 1, dtype=torch.bool), actions, torch.zeros(2, 2, dtype=torch.bool))
    torch.manual_seed(3)
    _, fit = policy.imitation_loss(batch, ImitationObjective())
    torch.manual_seed(3)  # the loss's draws, in its order: the noise, then each window's step k
    noise, steps = torch.randn(2, 2), torch.randint(0, 4, (2,))
    clean = np.array([[-0.5, 1.0], [0.0, -1.0]])  # (a − 2) / 2: the actions' range [0, 4] is [−1, 1]
    alpha_bar = _alpha_bars(4)[steps.numpy()][:, None]
    noisy = np.sqrt(alpha_bar) * clean + np.sqrt(1 - alpha_bar) * noise.numpy()
    target = noise.numpy() if prediction == "noise" else clean
    assert fit.item() == pytest.approx(np.mean((noisy - target) ** 2), rel=1e-5)


def test_ddim_denoises_from_the_last_noise_level_in_the_steps_worked_by_hand() -> None:
    policy = _linear(chunk=2, denoising_steps=100, sampling_steps=2).eval()
    c = 0.3  # ε_θ = c whatever its inputs
    with torch.no_grad():
        policy.denoiser.head.weight.zero_()
        policy.denoiser.head.bias.fill_(c)
    with torch.no_grad():
        sampled = policy.sample(torch.zeros(1, 1, 1), torch.Generator().manual_seed(5))
    x = torch.randn((1, 2), generator=torch.Generator().manual_seed(5)).numpy().astype(np.float64)
    alpha_bar = _alpha_bars(100)
    for k, previous in ((99, alpha_bar[49]), (49, 1.0)):  # trailing spacing: k = 99, 49; ᾱ = 1 below step 0
        clean = np.clip((x - np.sqrt(1 - alpha_bar[k]) * c) / np.sqrt(alpha_bar[k]), -1, 1)
        x = np.sqrt(previous) * clean + np.sqrt(1 - previous) * c
    np.testing.assert_allclose(sampled.numpy().reshape(-1), 2 + 2 * np.clip(x, -1, 1).reshape(-1), rtol=1e-5)


def test_a_denoiser_that_predicts_the_clean_chunk_steps_from_it_as_worked_by_hand() -> None:
    policy = _linear(chunk=2, denoising_steps=100, sampling_steps=2, prediction="sample").eval()
    a, c = 0.5, 0.3  # D_θ = Â⁰ = a·A^k + c whatever the rest of its inputs
    with torch.no_grad():
        policy.denoiser.head.weight.zero_()
        policy.denoiser.head.weight[:, :2] = a * torch.eye(2)
        policy.denoiser.head.bias.fill_(c)
        sampled = policy.sample(torch.zeros(1, 1, 1), torch.Generator().manual_seed(5))
    x = torch.randn((1, 2), generator=torch.Generator().manual_seed(5)).numpy().astype(np.float64)
    alpha_bar = _alpha_bars(100)
    clean = np.clip(a * x + c, -1, 1)
    noise = (x - np.sqrt(alpha_bar[99]) * clean) / np.sqrt(1 - alpha_bar[99])  # ε̂ from the noising equation
    x = np.sqrt(alpha_bar[49]) * clean + np.sqrt(1 - alpha_bar[49]) * noise
    clean = np.clip(a * x + c, -1, 1)  # the last step (ᾱ = 1 below step 0) lands on its Â⁰
    np.testing.assert_allclose(sampled.numpy().reshape(-1), 2 + 2 * clean.reshape(-1), rtol=1e-5)


def test_with_eta_one_each_step_adds_the_ddpm_posterior_noise_drawn_from_the_plans_generator() -> None:
    policy = _linear(chunk=2, denoising_steps=100, sampling_steps=2).eval()
    policy.config.sampling_noise = 1.0
    c = 0.3  # ε_θ = c whatever its inputs
    with torch.no_grad():
        policy.denoiser.head.weight.zero_()
        policy.denoiser.head.bias.fill_(c)
        sampled = policy.sample(torch.zeros(1, 1, 1), torch.Generator().manual_seed(5))
    draws = torch.Generator().manual_seed(5)  # the plan's noise, then one z per step, in that order
    x, z = (torch.randn((1, 2), generator=draws).numpy().astype(np.float64) for _ in range(2))
    alpha_bar = _alpha_bars(100)
    clean = np.clip((x - np.sqrt(1 - alpha_bar[99]) * c) / np.sqrt(alpha_bar[99]), -1, 1)
    sigma = np.sqrt((1 - alpha_bar[49]) / (1 - alpha_bar[99])) * np.sqrt(1 - alpha_bar[99] / alpha_bar[49])
    x = np.sqrt(alpha_bar[49]) * clean + np.sqrt(1 - alpha_bar[49] - sigma**2) * c + sigma * z
    clean = np.clip((x - np.sqrt(1 - alpha_bar[49]) * c) / np.sqrt(alpha_bar[49]), -1, 1)  # k' below 0: σ = 0
    np.testing.assert_allclose(sampled.numpy().reshape(-1), 2 + 2 * clean.reshape(-1), rtol=1e-4)  # float32 steps
    assert sigma > 0.1  # the noise this test checks is no rounding error


def test_an_ensemble_fits_each_member_scores_their_mean_and_samples_from_it() -> None:
    policy = _linear(chunk=2, denoising_steps=100, sampling_steps=2, members=2)
    constants = (0.1, 0.5)  # member m predicts ε = c_m whatever its inputs
    with torch.no_grad():
        for member, c in zip(policy.denoiser.members, constants):
            member.head.weight.zero_()
            member.head.bias.fill_(c)
    policy.average.load_state_dict(policy.denoiser.state_dict())
    batch = WindowBatch(torch.zeros(2, 1, 1), torch.zeros(2, 1, dtype=torch.bool), torch.ones(2, 2, 1), torch.zeros(2, 2, dtype=torch.bool))
    torch.manual_seed(3)
    _, fitted = policy.train().imitation_loss(batch, ImitationObjective())
    torch.manual_seed(3)
    noise = torch.randn(2, 2).numpy()
    assert fitted.item() == pytest.approx(np.mean([np.mean((c - noise) ** 2) for c in constants]), rel=1e-5)
    policy.updates += 1  # the moving average (a copy of the members) acts
    torch.manual_seed(3)
    _, scored = policy.eval().imitation_loss(batch, ImitationObjective())
    assert scored.item() == pytest.approx(np.mean((np.mean(constants) - noise) ** 2), rel=1e-5)
    single = _linear(chunk=2, denoising_steps=100, sampling_steps=2).eval()
    with torch.no_grad():
        single.denoiser.head.weight.zero_()
        single.denoiser.head.bias.fill_(np.mean(constants))
        expected = single.sample(torch.zeros(1, 1, 1), torch.Generator().manual_seed(5))
        sampled = policy.sample(torch.zeros(1, 1, 1), torch.Generator().manual_seed(5))
    torch.testing.assert_close(sampled, expected)  # the steps of one denoiser predicting the members' mean
    assert planned_weights(policy.config) == 2 * planned_weights(single.config)


def test_a_denoiser_target_other_than_the_clean_chunk_or_the_noise_is_refused_naming_both() -> None:
    with pytest.raises(ImitationError, match=r"^a diffusion policy's denoiser predicts one of sample, noise, not 'velocity'$"):
        _linear(chunk=2, prediction="velocity")


def test_a_run_written_before_the_target_and_eta_were_settings_loads_as_it_was_trained() -> None:
    """Such a run's config has neither field: its denoiser predicted the noise and its plans were deterministic."""
    config = _linear(chunk=2, prediction="sample").config.to_json() | {"sampling_noise": 1.0}
    older = {name: value for name, value in config.items() if name not in ("prediction", "sampling_noise", "members")}
    loaded = PolicyConfig.from_json(older)
    assert (loaded.prediction, loaded.sampling_noise, loaded.members) == ("noise", 0.0, 1)
    assert DiffusionPolicy(loaded).training_schedule.config.prediction_type == "epsilon"


def test_the_moving_average_follows_the_updates_with_the_warm_up_decay() -> None:
    policy = _linear(chunk=1)
    before = policy.average.head.bias.detach().clone()
    with torch.no_grad():
        policy.denoiser.head.bias.add_(1.0)
    policy.after_update()
    decay = 1 - 2.0**-EMA_POWER  # update u = 1: λ = 1 − (1 + u)^(−3/4)
    np.testing.assert_allclose(policy.average.head.bias.numpy(), decay * before.numpy() + (1 - decay) * (before.numpy() + 1), rtol=1e-6)
    assert int(policy.updates) == 1
    # Acting (eval mode) uses the average; training the current weights.
    assert policy.eval()._acting is policy.average and policy.train()._acting is policy.denoiser


def test_a_plan_executes_k_actions_then_samples_again_and_reset_repeats_an_episode(monkeypatch: pytest.MonkeyPatch) -> None:
    policy = _linear(chunk=4, sampling_steps=2, execute=2).eval()
    plans: list[np.ndarray] = []
    sample = policy.sample
    monkeypatch.setattr(policy, "sample", lambda history: plans.append(sample(history).numpy()) or torch.as_tensor(plans[-1]))
    first = [policy.predict(np.array([[0.0]]))[0, 0] for _ in range(4)]
    assert len(plans) == 2  # planned at steps 0 and 2
    assert first == [plans[0][0, 0, 0], plans[0][0, 1, 0], plans[1][0, 0, 0], plans[1][0, 1, 0]]  # two of each plan's four
    assert not np.array_equal(plans[0], plans[1])  # fresh noise for the second plan
    policy.reset()
    again = [policy.predict(np.array([[0.0]]))[0, 0] for _ in range(4)]
    assert again == first and np.array_equal(plans[2], plans[0])  # the noise seeded afresh at the episode's start


def test_diffusion_trains_evaluates_records_and_runs_dagger_through_the_command_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run"
    flags = ["--policy", "diffusion", "--history", "2", "--chunk", "4", "--hidden", "32,32", "--epochs", "2", "--epoch-samples", "512"]
    assert cli.main(["train", "bc", "--env", "Pendulum-v1", "--demos", str(DATASETS / "Pendulum-v1.mcap"), *flags, "--out", str(out), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["epochs"] == 2
    config = json.loads((out / "config.json").read_text())["policy"]
    settings = ("kind", "history", "chunk", "denoising_steps", "sampling_steps", "sampling_noise", "prediction")
    assert tuple(config[name] for name in settings) == ("diffusion", 2, 4, 100, 10, 1.0, "sample")
    policy = load_policy(out)
    assert isinstance(policy, DiffusionPolicy) and int(policy.updates) > 0
    assert cli.main(["eval", "policy", str(out), "--env", "Pendulum-v1", "--episodes", "1", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["episodes"] == 1
    demos = tmp_path / "by-diffusion.mcap"
    assert cli.main(["record", "--env", "Pendulum-v1", "--expert", str(out), "--episodes", "1", "--seed", "3", "--out", str(demos), "--quiet"]) == 0
    (episode,) = DemoFile(demos).read_episodes()
    policy.reset()  # the episode's plans again: the same noise, seeded at each episode's start
    np.testing.assert_array_equal(episode.actions, np.concatenate([policy.predict(o[None]) for o in episode.observations[:-1]]))
    dagger = tmp_path / "dagger"
    argv = ["train", "dagger", "--policy", "diffusion", "--chunk", "2", "--hidden", "16", "--env", "Pendulum-v1", "--expert", "scripted"]
    assert cli.main([*argv, "--rounds", "1", "--episodes-per-round", "1", "--epochs", "1", "--out", str(dagger), "--quiet"]) == 0
    assert json.loads((dagger / "config.json").read_text())["policy"]["kind"] == "diffusion"


@pytest.mark.parametrize(
    ("demos", "flags", "message"),
    [
        ("CartPole-v1", ["--chunk", "4"], "the diffusion policy samples Box actions, not Discrete ones"),
        ("Pendulum-v1", ["--sampling-steps", "20", "--denoising-steps", "10"], "--sampling-steps must be in [1, --denoising-steps 10], got 20"),
        ("Pendulum-v1", ["--denoising-steps", "0"], "--denoising-steps must be in [1, 10000], got 0"),
        ("Pendulum-v1", ["--sampling-noise", "1.5"], "--sampling-noise must be in [0, 1], got 1.5"),
        ("Pendulum-v1", ["--members", "0"], "--members must be in [1, 64], got 0"),
        ("Pendulum-v1", ["--policy", "chunk", "--members", "2"], "--members is for diffusion policies; the chunk policy is one network"),
        ("Pendulum-v1", ["--ensemble", "0.1"], "the diffusion policy executes its plans (--execute); leave --previous-action and --ensemble off"),
    ],
)
def test_what_the_diffusion_policy_cannot_do_is_refused_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], demos: str, flags: list[str], message: str
) -> None:
    out = tmp_path / "run"
    argv = ["train", "bc", "--env", demos, "--demos", str(DATASETS / f"{demos}.mcap"), "--policy", "diffusion", *flags, "--out", str(out)]
    assert cli.main(argv) == 1
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and message in error, error
    assert not out.exists()


def test_pusht_from_the_published_demos_to_coverage(testdata: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The issue's path at a tiny size: convert the zarr, train the diffusion head briefly, evaluate
    it in gym-pusht with the task's own measures (the full learning runs are in bench/)."""
    demos = tmp_path / "pusht.mcap"
    assert cli.main(["convert", str(testdata / PUSHT), "--env", "gym_pusht/PushT-v0", "--out", str(demos), "--quiet"]) == 0
    out = tmp_path / "run"
    flags = ["--policy", "diffusion", "--history", "2", "--chunk", "8", "--hidden", "64,64", "--epochs", "1", "--epoch-samples", "1024"]
    assert cli.main(["train", "bc", "--demos", str(demos), "--env", "gym_pusht/PushT-v0", *flags, "--out", str(out), "--quiet"]) == 0
    capsys.readouterr()
    assert cli.main(["eval", "policy", str(out), "--env", "gym_pusht/PushT-v0", "--episodes", "2", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert len(result["episode_coverage"]) == 2 and all(0 <= value <= 1 for value in result["episode_coverage"])
    assert result["mean_max_coverage"] == pytest.approx(np.mean(result["episode_coverage"]))
    assert result["success_rate"] in (0.0, 0.5, 1.0)
    # The buffer holds no rewards: the demos' zero return is no reference to normalise by.
    assert "normalized_return" not in result and "without rewards" in result["no_normalized_return"]
    assert cli.main(["eval", "policy", str(out), "--env", "gym_pusht/PushT-v0", "--episodes", "1"]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert printed[1].startswith("success rate ") and ", mean max coverage " in printed[1]


def test_angles_are_read_as_cosine_and_sine_so_a_turn_through_zero_is_no_jump() -> None:
    policy = build_policy("diffusion", gym.spaces.Box(-np.inf, np.inf, (2,), np.float32), ACTION, hidden_sizes=[], angles=[1])
    assert policy.obs_rms.mean.shape == (3,)  # x, cos θ, sin θ
    near_zero, near_two_pi = torch.tensor([[[5.0, 0.01]]]), torch.tensor([[[5.0, 2 * math.pi - 0.01]]])
    a, b = (policy.observed(h) for h in (near_zero, near_two_pi))
    assert torch.allclose(a[:, [0, 1]], b[:, [0, 1]], atol=1e-4) and torch.allclose(a[:, 2], -b[:, 2], atol=1e-4)
    np.testing.assert_allclose(a.numpy(), [[5.0, math.cos(0.01), math.sin(0.01)]], rtol=1e-5)  # fresh statistics: mean 0, std 1


@pytest.mark.parametrize(
    ("policy", "angles", "message"),
    [
        ("diffusion", "5", "--angles 5: the observation holds 3 numbers (positions 0 to 2)"),
        ("chunk", "3", "--angles 3: the observation holds 3 numbers (positions 0 to 2)"),
        ("actor-critic", "0", "--angles is read by the sequence policies (chunk, diffusion); the actor-critic reads observations as they are"),
    ],
)
def test_angles_outside_the_observation_or_for_the_actor_critic_are_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], policy: str, angles: str, message: str
) -> None:
    argv = ["train", "bc", "--env", "Pendulum-v1", "--demos", str(DATASETS / "Pendulum-v1.mcap"), "--policy", policy, "--angles", angles]
    assert cli.main([*argv, "--out", str(tmp_path / "run")]) == 1
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and message in error, error
