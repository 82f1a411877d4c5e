"""Stable-baselines3 zips load as ActorCritic policies without unpickling anything: the real
rl-baselines3-zoo CartPole expert (third-party test data) solves CartPole, and zips built here in
SB3's format cover the other architectures and every refusal."""

from __future__ import annotations

import base64
import io
import json
import pickle
import zipfile
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch
from sb3_zips import sb3_weights, space_entry
from support import run_cli
from test_cli import assert_one_line_error, last_json

from imitation.errors import ImitationError
from imitation.evaluation.policy import evaluate_policy
from imitation.experts.sb3 import load_sb3_policy
from imitation.policies import SingleObservationPolicy, check_policy_fits_env


@pytest.fixture
def cartpole_zip(testdata: Path) -> Path:
    return testdata / "experts" / "sb3_ppo_cartpole" / "CartPole-v1.zip"


def _write_zip(path: Path, members: dict[str, bytes]) -> Path:
    with zipfile.ZipFile(path, "w") as archive:
        for name, content in members.items():
            archive.writestr(name, content)
    return path


def _sb3_zip(path: Path, observation_space: gym.Space, action_space: gym.Space, weights: dict[str, torch.Tensor], **data: Any) -> Path:
    buffer = io.BytesIO()
    torch.save(weights, buffer)
    fields = {"observation_space": space_entry(observation_space), "action_space": space_entry(action_space), "policy_kwargs": {}, "use_sde": False}
    return _write_zip(path, {"data": json.dumps(fields | data).encode(), "policy.pth": buffer.getvalue(), "_stable_baselines3_version": b"2.3.0"})


def _relu_kwargs() -> dict[str, Any]:
    """policy_kwargs naming a class, as SB3 writes it: a pickle plus its items' str()."""
    kwargs = {"activation_fn": torch.nn.ReLU, "net_arch": {"pi": [32, 32], "vf": [32, 32]}}
    return {":type:": "<class 'dict'>", ":serialized:": base64.b64encode(pickle.dumps(kwargs, protocol=4)).decode(), "activation_fn": str(torch.nn.ReLU)}


PENDULUM_SPACES = (gym.spaces.Box(-8.0, 8.0, (3,), np.float32), gym.spaces.Box(-2.0, 2.0, (1,), np.float32))


def test_cartpole_expert_has_the_zips_architecture_and_solves_cartpole(cartpole_zip: Path) -> None:
    with zipfile.ZipFile(cartpole_zip) as archive:
        weights = torch.load(io.BytesIO(archive.read("policy.pth")), weights_only=True)
    policy = load_sb3_policy(cartpole_zip)
    hidden = [weights[f"mlp_extractor.policy_net.{2 * i}.weight"].shape[0] for i in range(len(policy.config.hidden_sizes))]
    assert policy.config.hidden_sizes == hidden == [64, 64]
    assert policy.config.activation == "tanh" and not policy.config.shared_trunk and not policy.is_continuous
    ours = policy.state_dict()
    for name, tensor in weights.items():
        mine = name.replace("mlp_extractor.policy_net", "actor_trunk").replace("mlp_extractor.value_net", "critic_trunk")
        mine = mine.replace("action_net", "action_head").replace("value_net", "value_head")
        assert torch.equal(ours[mine], tensor), name
    assert len(ours) == len(weights)
    env = gym.make("CartPole-v1")
    try:
        check_policy_fits_env(policy, env, "test")
        result = evaluate_policy(SingleObservationPolicy(policy), env, episodes=10, seed=0)
    finally:
        env.close()
    assert result["mean_return"] >= 475, result["returns"]


def test_loading_never_unpickles(cartpole_zip: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    relu_zip = _sb3_zip(tmp_path / "relu.zip", *PENDULUM_SPACES, sb3_weights(3, 1, pi=[32, 32], vf=[32, 32], box=True), policy_kwargs=_relu_kwargs())

    def refuse(*args: Any, **kwargs: Any) -> None:
        raise AssertionError("the loader unpickled something")

    torch_load = torch.load

    def weights_only_load(*args: Any, **kwargs: Any) -> Any:
        assert kwargs.get("weights_only") is True, "torch.load without weights_only=True"
        return torch_load(*args, **kwargs)

    monkeypatch.setattr(pickle, "loads", refuse)
    monkeypatch.setattr(pickle, "load", refuse)
    monkeypatch.setattr(pickle, "Unpickler", refuse)
    monkeypatch.setattr(torch, "load", weights_only_load)
    assert load_sb3_policy(cartpole_zip).config.activation == "tanh"
    assert load_sb3_policy(relu_zip).config.activation == "relu"


@pytest.mark.parametrize("shared", [False, True])
def test_box_actions_relu_and_shared_trunk(tmp_path: Path, shared: bool) -> None:
    sizes = {"shared": [32, 32], "pi": [], "vf": []} if shared else {"pi": [32, 32], "vf": [32, 32]}
    weights = sb3_weights(3, 1, box=True, **sizes)
    policy = load_sb3_policy(_sb3_zip(tmp_path / "pendulum.zip", *PENDULUM_SPACES, weights, policy_kwargs=_relu_kwargs()))
    assert policy.config.hidden_sizes == [32, 32] and policy.config.activation == "relu" and policy.config.shared_trunk is shared
    assert policy.is_continuous and torch.equal(policy.log_std.data, weights["log_std"])
    assert policy.action_high.tolist() == [2.0]
    env = gym.make("Pendulum-v1")
    try:
        check_policy_fits_env(policy, env, "test")
        observation, _ = env.reset(seed=0)
        action = SingleObservationPolicy(policy)(observation)
    finally:
        env.close()
    assert action.shape == (1,) and -2.0 <= action[0] <= 2.0


def _bad_zip(tmp_path: Path, case: str) -> Path:
    spaces = (gym.spaces.Box(-1.0, 1.0, (4,), np.float32), gym.spaces.Discrete(2))
    path = tmp_path / f"{case}.zip"
    if case == "not a zip":
        path.write_text("this is not a zip file\n")
        return path
    if case == "no policy.pth":
        return _write_zip(path, {"data": b"{}"})
    if case == "CNN weights":
        weights = sb3_weights(4, 2, pi=[64], vf=[64]) | {"features_extractor.cnn.0.weight": torch.randn(32, 4, 8, 8)}
        return _sb3_zip(path, *spaces, weights)
    if case == "actor and critic differ":
        return _sb3_zip(path, *spaces, sb3_weights(4, 2, pi=[64, 64], vf=[256, 256]))
    if case == "weights do not fit spaces":
        return _sb3_zip(path, *spaces, sb3_weights(4, 3, pi=[64], vf=[64]))
    if case == "policy.pth not a state dict":
        buffer = io.BytesIO()
        torch.save([torch.zeros(1)], buffer)
        return _write_zip(path, {"data": b"{}", "policy.pth": buffer.getvalue()})
    raise ValueError(case)


@pytest.mark.parametrize(
    ("case", "fragment"),
    [
        ("not a zip", "cannot read as a stable-baselines3 zip"),
        ("no policy.pth", "no policy.pth"),
        ("CNN weights", "features_extractor.cnn.0.weight"),
        ("actor and critic differ", "differ from critic hidden sizes [256, 256]"),
        ("weights do not fit spaces", "does not fit"),
        ("policy.pth not a state dict", "not a state dict"),
    ],
)
def test_bad_zips_give_one_line_errors_naming_the_file(tmp_path: Path, case: str, fragment: str) -> None:
    path = _bad_zip(tmp_path, case)
    with pytest.raises(ImitationError) as excinfo:
        load_sb3_policy(path)
    message = str(excinfo.value)
    assert "\n" not in message and message.startswith(str(path)) and fragment in message, message


def test_a_gsde_policy_acts_by_its_mean(tmp_path: Path) -> None:
    """gSDE's noise weights (a latent × actions matrix where a plain Gaussian has a vector) are not
    needed to act as an expert: the action is the mean, action_net(latent), clipped to the bounds."""
    weights = sb3_weights(3, 1, pi=[16], vf=[16], box=True)
    weights["log_std"] = torch.randn(16, 1)
    policy = load_sb3_policy(_sb3_zip(tmp_path / "sde.zip", *PENDULUM_SPACES, weights, use_sde=True))
    observations = torch.randn(32, 3)
    latent = torch.tanh(observations @ weights["mlp_extractor.policy_net.0.weight"].T + weights["mlp_extractor.policy_net.0.bias"])
    mean = latent @ weights["action_net.weight"].T + weights["action_net.bias"]
    expected = mean.clamp(-2.0, 2.0).numpy()
    np.testing.assert_allclose(policy.predict(observations.numpy()), expected, rtol=1e-5, atol=1e-6)


def test_record_with_sb3_expert(cartpole_zip: Path, tmp_path: Path) -> None:
    out = tmp_path / "sb3.mcap"
    record = last_json(run_cli("record", "--env", "CartPole-v1", "--expert", f"sb3:{cartpole_zip}", "--episodes", "2", "--seed", "0", "--out", str(out), "--json"))
    assert record["episodes"] == 2 and record["mean_return"] >= 475 and out.is_file()


def test_sb3_expert_for_another_env_is_refused(cartpole_zip: Path, tmp_path: Path) -> None:
    result = run_cli("record", "--env", "Pendulum-v1", "--expert", f"sb3:{cartpole_zip}", "--episodes", "1", "--out", str(tmp_path / "x.mcap"))
    assert_one_line_error(result, f"--expert sb3:{cartpole_zip}", "observation space")


def test_eval_policy_of_a_zip_points_to_the_command_that_scores_it(cartpole_zip: Path, tmp_path: Path) -> None:
    """`eval policy` reads run directories; given a stable-baselines3 zip (with or without sb3:)
    it names the command that scores one, and that command, run as printed, does."""
    for spec in (f"sb3:{cartpole_zip}", str(cartpole_zip)):
        result = run_cli("eval", "policy", spec, "--env", "CartPole-v1", "--episodes", "2", "--seed", "3")
        assert_one_line_error(result, f"{spec}: eval policy scores a run directory; a stable-baselines3 zip is scored by recording its episodes")
        assert "not a run directory" not in result.stderr
    command = result.stderr.split("recording its episodes: imitation ", 1)[1].split(" (it prints", 1)[0].split()
    assert command == ["record", "--env", "CartPole-v1", "--expert", f"sb3:{cartpole_zip}", "--episodes", "2", "--seed", "3", "--out", "F.mcap"]
    scored = run_cli(*command[:-1], str(tmp_path / "F.mcap"))
    assert scored.returncode == 0, scored.stderr
    assert "recorded 2 episodes of CartPole-v1" in scored.stdout and "mean return 500.00 (min 500.00, max 500.00)" in scored.stdout
