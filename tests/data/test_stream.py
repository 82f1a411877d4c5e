"""StreamingLoader: every training transition once per epoch, batches mixing episodes, frame stacks
as `stack_frames` builds them, a sequence policy's windows as the in-memory loader gathers them, the
memory budget honoured, the same batches for the same seed; and BC trained from the stream through
the command line."""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from support import run_cli_many

from imitation.algorithms.bc import BCConfig, BehaviouralCloning, policy_options
from imitation.checkpoints import snapshot
from imitation.data.dataset import DemoDataset
from imitation.data.loader import load_transitions, transitions_to_torch
from imitation.data.mcap.writer import write_episodes
from imitation.data.stream import StreamingLoader
from imitation.data.types import Episode
from imitation.data.windows import WindowSpec, gather_windows, window_index
from imitation.envs.pixels import stack_frames, stacked_space
from imitation.errors import ImitationError
from imitation.policies import make_policy

H, W = 12, 10
SPACE = gym.spaces.Dict(
    {"pixels": gym.spaces.Box(0, 255, (H, W, 1), np.uint8), "state": gym.spaces.Box(-1, 1, (2,), np.float32)}
)
ACTIONS = gym.spaces.Discrete(3)


def _episode(k: int, steps: int) -> Episode:
    """Frames whose first pixel is the step and second the episode: rows are recognisable in a batch."""
    rng = np.random.default_rng(k)
    pixels = rng.integers(0, 256, (steps + 1, H, W, 1), dtype=np.uint8)
    pixels[:, 0, 0, 0] = np.arange(steps + 1)
    pixels[:, 0, 1, 0] = k
    return Episode(
        observations={"pixels": pixels, "state": rng.uniform(-1, 1, (steps + 1, 2)).astype(np.float32)},
        actions=rng.integers(0, 3, steps),
        rewards=rng.normal(size=steps),
        truncated=True,
    )


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> DemoDataset:
    path = tmp_path_factory.mktemp("stream") / "pixels.mcap"
    episodes = [_episode(k, 20 + 7 * k) for k in range(12)]
    write_episodes(path, episodes, env_id="Synthetic-v0", observation_space=SPACE, action_space=ACTIONS)
    return DemoDataset([path])


TRAIN = [0, 1, 2, 4, 5, 7, 8, 9, 11]


def _loader(dataset: DemoDataset, **options) -> StreamingLoader:
    settings = {"batch_size": 16, "memory": 40 * 16 * (H * W * 3 + 64), "frames": 3, "image_keys": ["pixels"], "seed": 3}
    return StreamingLoader(dataset, TRAIN, **(settings | options))


def _rows(batch) -> list[tuple[int, int]]:
    """(episode, step) of each row, read from the frames' marker pixels."""
    newest = batch.observations["pixels"][:, -1, 0, :2, 0].numpy()
    assert np.array_equal(newest[:, 1], batch.episode_index.numpy())
    return [(int(k), int(t)) for t, k in newest]


def test_every_transition_exactly_once_per_epoch(dataset: DemoDataset) -> None:
    loader = _loader(dataset)
    for _ in range(2):
        seen = [row for batch in loader for row in _rows(batch)]
        expected = [(k, t) for k in TRAIN for t in range(dataset.episodes[k].length)]
        assert sorted(seen) == sorted(expected) and len(seen) == loader.transitions
    assert len(list(loader)) == len(loader)


def test_batches_mix_episodes(dataset: DemoDataset) -> None:
    batches = list(_loader(dataset))
    mixed = [len(set(batch.episode_index.tolist())) for batch in batches[:-1]]
    assert min(mixed) >= 3 and np.mean(mixed) >= 5
    first_steps = [t for t in (row[1] for row in _rows(batches[0]))]
    assert first_steps != sorted(first_steps)  # rows within an episode are shuffled too


def test_frame_stacks_equal_stack_frames(dataset: DemoDataset) -> None:
    loaded = load_transitions(dataset, episodes=TRAIN, next_observations=False)
    stacked = stack_frames(loaded.observations, loaded.episode_index, 3, ["pixels"])
    steps = loaded.observations["pixels"][:, 0, 0, 0]
    where = {(int(k), int(t)): i for i, (k, t) in enumerate(zip(loaded.episode_index, steps))}
    for batch in _loader(dataset):
        rows = [where[row] for row in _rows(batch)]
        assert np.array_equal(batch.observations["pixels"].numpy(), stacked["pixels"][rows])
        assert np.array_equal(batch.observations["state"].numpy(), loaded.observations["state"][rows])
        assert np.array_equal(batch.actions.numpy(), loaded.actions[rows])
        assert np.array_equal(batch.rewards.numpy(), loaded.rewards[rows])


@pytest.mark.parametrize("shuffle", [False, True])
def test_windows_equal_the_in_memory_windows(dataset: DemoDataset, shuffle: bool) -> None:
    spec = WindowSpec(observations=3, actions=5)
    loaded = load_transitions(dataset, episodes=TRAIN, next_observations=False)
    expected = gather_windows(transitions_to_torch(loaded), window_index(loaded.episode_index, spec), np.arange(len(loaded)))
    steps = loaded.observations["pixels"][:, 0, 0, 0]
    where = {(int(k), int(t)): i for i, (k, t) in enumerate(zip(loaded.episode_index, steps))}
    loader = _loader(dataset, frames=1, window=spec, shuffle=shuffle)
    seen = []
    for batch in loader:
        newest = batch.observations["pixels"][:, -1, 0, :2, 0].numpy()  # the window's current step and episode
        rows = [where[(int(k), int(t))] for t, k in newest]
        for name in ("observation_pad", "action_pad", "actions"):
            assert torch.equal(getattr(batch, name), getattr(expected, name)[rows]), name
        for key in ("pixels", "state"):
            assert torch.equal(batch.observations[key], expected.observations[key][rows]), key
        seen += rows
    assert sorted(seen) == list(range(len(loaded)))  # every window once
    assert bool(expected.observation_pad.any()) and bool(expected.action_pad.any())  # the edges were exercised
    with pytest.raises(ImitationError, match="windows of observations or stacks of frames, not both"):
        _loader(dataset, window=spec)


def test_memory_budget_bounds_what_is_held(dataset: DemoDataset) -> None:
    loader = _loader(dataset)
    list(loader)
    longest = max(dataset.episodes[k].length for k in TRAIN) + 1
    episode_bytes = longest * (H * W + 2 * 4 + 8 + 8 + 2 + 8)  # frame, state, action, reward, flags, episode
    assert 0 < loader.peak_bytes <= loader.memory + episode_bytes
    assert loader.capacity * loader.row_bytes <= loader.memory // 2
    with pytest.raises(ImitationError, match="fewer rows than one batch"):
        _loader(dataset, memory=1000)


def test_same_seed_same_batches(dataset: DemoDataset) -> None:
    def epochs(seed: int) -> list[list[tuple[int, int]]]:
        loader = _loader(dataset, seed=seed)
        return [[row for batch in loader for row in _rows(batch)] for _ in range(2)]

    first = epochs(3)
    assert first == epochs(3)
    assert first[0] != first[1]  # each epoch in its own order
    assert first != epochs(4)


def test_generator_state_resumes_the_next_epoch(dataset: DemoDataset) -> None:
    loader = _loader(dataset)
    list(loader)
    state = loader.generator_state()
    second = [row for batch in loader for row in _rows(batch)]
    resumed = _loader(dataset, seed=99)
    resumed.set_generator_state(state)
    assert [row for batch in resumed for row in _rows(batch)] == second


def test_in_order_and_early_stop(dataset: DemoDataset) -> None:
    rows = [row for batch in _loader(dataset).in_order() for row in _rows(batch)]
    assert rows == [(k, t) for k in TRAIN for t in range(dataset.episodes[k].length)]
    loader = _loader(dataset)
    for _ in zip(range(2), loader):  # a consumer that stops early leaves no thread behind
        pass
    assert len(list(loader)) == len(loader)


def test_bc_trains_from_the_stream_through_the_cli(tmp_path: Path) -> None:
    demos, out = tmp_path / "pixels.mcap", tmp_path / "run"
    record = ["record", "--env", "CartPole-v1", "--expert", "random", "--pixels", "36x36", "--grayscale", "--episodes", "3"]
    train = ["train", "bc", "--demos", demos, "--epochs", "2", "--epoch-samples", "64", "--batch-size", "32"]
    streamed = [*train, "--device", "cpu", "--stream-memory", "4", "--out", out, "--quiet", "--json"]
    recorded, trained, refused = run_cli_many(
        [[*record, "--out", demos, "--quiet"], streamed, [*train, "--stream-memory", "0", "--out", tmp_path / "no"]]
    )
    assert recorded.returncode == 0, recorded.stderr
    assert trained.returncode == 0, trained.stderr
    result = json.loads(trained.stdout)
    assert result["epochs"] == 2 and result["train_transitions"] > 0 and result["validation_transitions"] > 0
    assert np.isfinite(result["best_validation_loss"])
    assert refused.returncode != 0 and "--stream-memory" in refused.stderr


def test_bc_resumes_a_stream_exactly(dataset: DemoDataset) -> None:
    cnn = {"channels": [4], "kernels": [3], "strides": [1], "features": 16}
    config = BCConfig(epochs=3, batch_size=16, epoch_samples=0, frame_stack=3, hidden_sizes=[16], cnn=cnn, device="cpu")

    def learner() -> BehaviouralCloning:
        options = {"batch_size": 16, "memory": 10**6, "frames": 3, "image_keys": ["pixels"]}
        train = StreamingLoader(dataset, TRAIN, seed=0, **options)
        validation = StreamingLoader(dataset, [3, 6], shuffle=False, **options)
        torch.manual_seed(0)  # the policy's initial weights (a job seeds everything first)
        policy = make_policy(
            stacked_space(SPACE, 3), ACTIONS, **policy_options(config, train.transitions), frame_stack=3, cnn=cnn
        )
        return BehaviouralCloning(policy, train, validation, config)

    first = learner()
    first.step()
    checkpoint = snapshot(*first.state_dict())  # copies: the live state goes on training
    continued = [first.step() for _ in range(2)]
    resumed = learner()
    resumed.load_state_dict(checkpoint)
    again = [resumed.step() for _ in range(2)]
    for row, other in zip(continued, again):
        assert (row["train_loss"], row["validation_loss"]) == (other["train_loss"], other["validation_loss"])
