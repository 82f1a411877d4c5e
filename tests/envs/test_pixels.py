"""Pixel observations: rendered frames, frame stacks online and offline, the CNN policy, random
shift, and `record --pixels` → `train bc` / `train dagger` → `eval policy` through the CLI."""

from __future__ import annotations

import json
import os

import gymnasium as gym
import numpy as np
import pytest
import torch
from support import run_cli

from imitation.algorithms.bc import BCConfig, BehaviouralCloning, default_threads
from imitation.data.loader import TransitionTensors
from imitation.data.dataset import DemoDataset
from imitation.encoders import CNNConfig, random_shift
from imitation.envs.action_noise import ActionNoise
from imitation.envs.pixels import (
    PixelRecipe,
    StackFrames,
    frame_stack_index,
    make_pixel_env,
    stack_frames,
)
from imitation.errors import ImitationError
from imitation.policies import make_policy
from imitation.policy_kinds import load_policy

SMALL_CNN = {"channels": [8, 16], "kernels": [4, 3], "strides": [2, 2], "features": 32}


def test_recipe_parses_and_round_trips() -> None:
    recipe = PixelRecipe.parse("40x60", grayscale=True, crop="10,20,100,200")
    assert (recipe.height, recipe.width, recipe.grayscale, recipe.crop) == (40, 60, True, (10, 20, 100, 200))
    assert PixelRecipe.from_json(json.loads(json.dumps(recipe.to_json()))) == recipe
    for size in ("84", "0x84", "84x", "ax84"):
        with pytest.raises(ImitationError, match="HEIGHTxWIDTH"):
            PixelRecipe.parse(size)
    with pytest.raises(ImitationError, match="TOP,LEFT,HEIGHT,WIDTH"):
        PixelRecipe.parse("84x84", crop="1,2,3")
    for bad in ({"size": [84]}, {"size": [84, 0]}, {"size": [84, 84], "crop": [0, 0, 0, 5]}, "84x84"):
        with pytest.raises(ValueError):
            PixelRecipe.from_json(bad)


def test_recorded_pixels_reads_the_recipe_and_stack_record_wrote() -> None:
    from imitation.envs.pixels import recorded_pixels

    recorded = {"pixels": {"size": [36, 36], "grayscale": True, "frame_stack": 2}}
    assert recorded_pixels({}, "d.mcap") == (None, 1) and recorded_pixels({}, "d.mcap", frame_stack=3) == (None, 3)
    assert recorded_pixels(recorded, "d.mcap") == (PixelRecipe(36, 36, grayscale=True), 2)
    assert recorded_pixels(recorded, "d.mcap", frame_stack=4) == (PixelRecipe(36, 36, grayscale=True), 4)
    damaged = {"pixels": {"size": [36, 36], "frame_stack": 99}}
    assert recorded_pixels(damaged, "d.mcap", frame_stack=1) == (PixelRecipe(36, 36), 1), "a given stack overrides a damaged one"
    with pytest.raises(ImitationError, match=r"^d.mcap: user metadata 'pixels': frame_stack must be in \[1, 64\], got 99$"):
        recorded_pixels(damaged, "d.mcap")
    with pytest.raises(ImitationError, match=r"^d.mcap: user metadata 'pixels': a pixel recipe is"):
        recorded_pixels({"pixels": {"size": "big"}}, "d.mcap", frame_stack=1)


def test_frames_crop_resize_and_grayscale() -> None:
    image = np.zeros((40, 60, 3), dtype=np.uint8)
    image[10:20, 30:40] = (255, 0, 0)  # a red square, inside the crop
    frame = PixelRecipe(10, 10, False, (10, 30, 10, 10)).frame(image)
    assert frame.shape == (10, 10, 3) and (frame == (255, 0, 0)).all()
    luma = PixelRecipe(10, 10, True, (10, 30, 10, 10)).frame(image)
    assert luma.shape == (10, 10, 1) and (luma == 76).all()  # 0.299 · 255
    with pytest.raises(ImitationError, match="reaches outside"):
        PixelRecipe(10, 10, False, (35, 0, 10, 10)).frame(image)


def test_pixel_env_keeps_the_state_beside_the_frames() -> None:
    env = make_pixel_env("CartPole-v1", PixelRecipe(21, 32, True))
    observation, _ = env.reset(seed=3)
    state, _ = gym.make("CartPole-v1").reset(seed=3)
    assert observation["pixels"].shape == (21, 32, 1) and observation["pixels"].dtype == np.uint8
    np.testing.assert_array_equal(observation["state"], state)
    assert env.observation_space.contains(observation)


def test_offline_stacks_equal_what_the_env_shows() -> None:
    """A stacked episode rebuilt from its newest frames (as files hold them) equals the stacks
    StackFrames showed, the reset frame repeated at the start."""
    env = StackFrames(make_pixel_env("CartPole-v1", PixelRecipe(16, 24, True)), 3)
    shown = []
    observation, _ = env.reset(seed=0)
    shown.append(observation["pixels"])
    for action in [1, 1, 0, 1, 0, 0, 1]:
        observation, *_ = env.step(action)
        shown.append(observation["pixels"])
    stacks = np.stack(shown)
    assert (stacks[0] == stacks[0][0]).all() and not (stacks[3][0] == stacks[3][2]).all()
    episodes = np.array([0] * len(stacks))
    np.testing.assert_array_equal(stack_frames({"pixels": stacks[:, -1]}, episodes, 3, ["pixels"])["pixels"], stacks)
    np.testing.assert_array_equal(frame_stack_index(np.array([0, 0, 1, 1, 1]), 2), [[0, 0], [0, 1], [2, 2], [2, 3], [3, 4]])


def test_random_shift_moves_each_sample_with_edges_replicated() -> None:
    frames = torch.arange(2 * 2 * 5 * 5, dtype=torch.uint8).reshape(2, 2, 5, 5, 1)
    generator = torch.Generator().manual_seed(0)
    shifted = random_shift(frames, 2, generator)
    dy, dx = torch.randint(0, 5, (2, 2), generator=torch.Generator().manual_seed(0)) - 2
    for i in range(2):
        rows = (torch.arange(5) + dy[i]).clamp(0, 4)
        columns = (torch.arange(5) + dx[i]).clamp(0, 4)
        expected = frames[i][:, rows][:, :, columns]  # both frames of a sample move together
        assert torch.equal(shifted[i], expected)
    assert torch.equal(random_shift(frames, 0), frames)


def test_cnn_policy_reads_only_its_keys() -> None:
    env = StackFrames(make_pixel_env("CartPole-v1", PixelRecipe(24, 24, True)), 2)
    policy = make_policy(env.observation_space, env.action_space, frame_stack=2, observation_keys=["pixels"], cnn=SMALL_CNN)
    observation, _ = env.reset(seed=0)
    batch = {key: torch.as_tensor(value)[None] for key, value in observation.items()}
    features = policy.encode(batch)
    assert features.shape == (1, 32)
    changed_state = batch | {"state": batch["state"] + 100}
    assert torch.equal(policy.encode(changed_state), features)
    changed_pixels = batch | {"pixels": 255 - batch["pixels"]}
    assert not torch.equal(policy.encode(changed_pixels), features)
    both = make_policy(env.observation_space, env.action_space, frame_stack=2, cnn=SMALL_CNN)
    assert both.encode(batch).shape == (1, 32 + 4)  # the state's 4 numbers beside the CNN's features
    with pytest.raises(ImitationError, match="too small for the CNN"):
        make_policy(env.observation_space, env.action_space, frame_stack=2, cnn=CNNConfig().to_json())


def test_bc_trains_a_cnn_on_every_core_and_an_mlp_on_one() -> None:
    env = StackFrames(make_pixel_env("CartPole-v1", PixelRecipe(24, 24, True)), 2)
    cnn = make_policy(env.observation_space, env.action_space, frame_stack=2, observation_keys=["pixels"], cnn=SMALL_CNN)
    mlp = make_policy(env.observation_space, env.action_space, frame_stack=2, observation_keys=["state"])
    assert default_threads(cnn) == len(os.sched_getaffinity(0))
    assert default_threads(mlp) == 1


def test_mixed_precision_bc_runs_the_cnn_in_bfloat16_on_the_cpu_and_keeps_float32_weights() -> None:
    space = gym.spaces.Dict({"pixels": gym.spaces.Box(0, 255, (2, 24, 24, 1), np.uint8)})
    generator = torch.Generator().manual_seed(0)
    frames = torch.randint(0, 256, (64, 2, 24, 24, 1), dtype=torch.uint8, generator=generator)
    labels = (frames[:, -1, :12].float().mean((1, 2, 3)) > frames[:, -1, 12:].float().mean((1, 2, 3))).long()
    n = len(labels)
    data = TransitionTensors(
        observations={"pixels": frames}, actions=labels, rewards=torch.zeros(n), next_observations=None,
        terminated=torch.zeros(n, dtype=torch.bool), truncated=torch.zeros(n, dtype=torch.bool),
        episode_index=torch.zeros(n, dtype=torch.long),
    )  # fmt: skip
    trained = {}
    for mixed in (False, True):
        torch.manual_seed(0)
        policy = make_policy(space, gym.spaces.Discrete(2), frame_stack=2, normalize_observations=True, cnn=SMALL_CNN)
        config = BCConfig(epochs=1, batch_size=16, epoch_samples=64, random_shift=0, mixed_precision=mixed, threads=1)
        learner = BehaviouralCloning(policy, data, None, config)
        dtypes = []
        hook = policy.image_encoders[0].convolutions[0].register_forward_hook(lambda m, i, o: dtypes.append(o.dtype))
        learner.step()
        hook.remove()
        assert dtypes and set(dtypes) == {torch.bfloat16 if mixed else torch.float32}
        assert all(p.dtype == torch.float32 for p in policy.parameters())
        trained[mixed] = torch.cat([p.detach().reshape(-1) for p in policy.parameters()])
    assert not torch.equal(trained[False], trained[True])  # the half-precision forward pass changed the steps
    torch.testing.assert_close(trained[True], trained[False], rtol=0, atol=0.05)  # ... but only by rounding


def test_pixels_are_standardised_per_channel_by_the_newest_frames() -> None:
    space = gym.spaces.Dict({"pixels": gym.spaces.Box(0, 255, (2, 20, 20, 3), np.uint8)})
    policy = make_policy(space, gym.spaces.Discrete(2), frame_stack=2, normalize_observations=True, cnn=SMALL_CNN)
    generator = torch.Generator().manual_seed(0)
    frames = torch.randint(0, 256, (50, 2, 20, 20, 3), dtype=torch.uint8, generator=generator)
    frames[:, 0] = 255  # the older frame of each stack is a repeat: it must not count twice
    frames[..., 1] //= 4
    policy.update_normalizer({"pixels": frames})
    newest = frames[:, -1].reshape(-1, 3).double()
    (statistics,) = policy.pixel_rms
    torch.testing.assert_close(statistics.mean, newest.mean(0))
    torch.testing.assert_close(statistics.var, newest.var(0, unbiased=False), rtol=1e-6, atol=1e-6)
    scaled = policy._scaled_frames({"pixels": frames}, 0)
    expected = ((frames.double() - newest.mean(0)) / newest.std(0, unbiased=False)).clamp(-10, 10)
    torch.testing.assert_close(scaled, expected.float(), rtol=1e-5, atol=1e-5)
    raw = make_policy(space, gym.spaces.Discrete(2), frame_stack=2, cnn=SMALL_CNN)
    assert raw.pixel_rms is None
    torch.testing.assert_close(raw._scaled_frames({"pixels": frames}, 0), frames.float() / 255)


def test_action_noise_executes_random_actions_and_keeps_the_label() -> None:
    env = ActionNoise(gym.make("CartPole-v1"), 1.0, seed=0)
    env.reset(seed=0)
    executed = []
    for _ in range(50):
        before = env.unwrapped.state.copy()
        _, _, terminated, _, _ = env.step(0)  # the given action is always 0; with ε = 1 the env pushes either way
        executed.append(env.unwrapped.state[1] > before[1])  # pushed right
        if terminated:
            env.reset()
    assert 10 < sum(executed) < 40


def test_biased_action_noise_pushes_one_way_per_episode() -> None:
    """With bias 1 every noisy step of an episode executes that episode's one action: the cart is pushed
    the same way throughout (the given action, 0, is never executed with ε = 1); episodes differ."""
    env = ActionNoise(gym.make("CartPole-v1"), 1.0, seed=3, bias=1.0)
    directions = []
    for episode in range(8):
        env.reset(seed=episode)
        pushes = set()
        for _ in range(5):
            before = env.unwrapped.state.copy()
            env.step(0)
            pushes.add(bool(env.unwrapped.state[1] > before[1]))
        assert len(pushes) == 1, f"episode {episode} pushed both ways"
        directions.append(pushes.pop())
    assert 0 < sum(directions) < 8


def test_zero_bias_draws_the_same_noise_as_uniform_dart() -> None:
    """Bias 0 must not change the random stream (recordings made before the option stay reproducible):
    the executed pushes are those of ε-uniform noise drawn from the seed's two generators."""
    env = ActionNoise(gym.make("CartPole-v1"), 0.5, seed=7, bias=0.0)
    rng, space = np.random.default_rng(7), gym.spaces.Discrete(2)
    space.seed(7)
    for episode in range(3):
        env.reset(seed=episode)
        for _ in range(10):
            expected = int(space.sample()) if rng.random() < 0.5 else 0
            before = env.unwrapped.state.copy()
            env.step(0)
            assert int(env.unwrapped.state[1] > before[1]) == expected


def test_record_train_and_eval_pixel_cartpole_through_the_cli(tmp_path) -> None:
    demos = tmp_path / "pixels.mcap"
    recorded = run_cli(
        "record", "--env", "CartPole-v1", "--pixels", "36x36", "--grayscale", "--crop", "100,150,250,300",
        "--frame-stack", "2", "--episodes", "2", "--action-noise", "0.2", "--noise-bias", "0.5",
        "--out", str(demos), "--quiet",
    )  # fmt: skip
    assert recorded.returncode == 0, recorded.stderr
    dataset = DemoDataset(demos)
    assert dataset.observation_space["pixels"] == gym.spaces.Box(0, 255, (36, 36, 1), np.uint8)
    assert dataset.files[0].user_metadata["pixels"] == {
        "size": [36, 36], "grayscale": True, "crop": [100, 150, 250, 300], "frame_stack": 2,
    }  # fmt: skip
    assert dataset.files[0].user_metadata["action_noise"] == 0.2
    assert dataset.files[0].user_metadata["noise_bias"] == 0.5

    run = tmp_path / "bc"
    trained = run_cli(
        "train", "bc", "--demos", str(demos), "--env", "CartPole-v1", "--epochs", "2", "--epoch-samples", "256",
        "--out", str(run), "--quiet", "--json",
    )  # fmt: skip
    assert trained.returncode == 0, trained.stderr
    policy = load_policy(run)
    assert policy.config.frame_stack == 2 and policy.config.observation_keys == ["pixels"]
    assert policy.observation_space["pixels"].shape == (2, 36, 36, 1)
    (pixels,) = policy.pixel_statistics  # fitted by BC: a mostly white render, not the unfitted (0, 1)
    assert 150 < float(pixels.mean) < 255 and float(pixels.var) > 100 and float(pixels.count) > 36 * 36
    video = tmp_path / "bc.gif"
    evaluated = run_cli("eval", "policy", str(run), "--env", "CartPole-v1", "--episodes", "2", "--video", str(video), "--json")
    assert evaluated.returncode == 0, evaluated.stderr
    result = json.loads(evaluated.stdout)
    assert result["episodes"] == 2 and video.stat().st_size > 0
    assert result["video"]["return"] == result["returns"][0]  # the video's episode is eval's first, seen as in training


def test_dagger_on_pixels_writes_single_frames_and_learns_on_stacks(tmp_path) -> None:
    run = tmp_path / "dagger"
    result = run_cli(
        "train", "dagger", "--env", "CartPole-v1", "--expert", "scripted", "--pixels", "36x36", "--grayscale",
        "--frame-stack", "3", "--rounds", "2", "--episodes-per-round", "1", "--epochs", "1", "--out", str(run), "--quiet",
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    round_file = DemoDataset(run / "rounds" / "round-02.mcap")
    assert round_file.observation_space["pixels"].shape == (36, 36, 1)
    assert round_file.files[0].user_metadata["pixels"]["frame_stack"] == 3
    episode = round_file[0]
    assert episode.observations["pixels"].shape[1:] == (36, 36, 1) and episode.observations["state"].shape[1:] == (4,)
    assert load_policy(run).observation_space["pixels"].shape == (3, 36, 36, 1)
