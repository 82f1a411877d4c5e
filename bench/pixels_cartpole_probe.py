"""Pixel CartPole BC probe: variants of the image pipeline, trained outside the command line.

One recording (`record --pixels 84x84 --grayscale --crop 150,216,168,168 --frame-stack 4
--action-noise P`), its last 4 episodes held out, and a BC network trained on the rest for a
fixed number of Adam steps (batch 128, random shift 4), then rolled out deterministically. The
variants (those from `--newest-diff` on are remedies aimed at copycat BC; the figures of all of them are
in bench/RESULTS.md's Pixel CartPole sections):

- `--scale raw|standardised`: pixels divided by 255, or standardised by the training frames' mean
  and std (what the policies do with normalised observations);
- `--head plain|library|keypoints`: a Nature CNN with a 512 → 256 → 2 head in PyTorch's default
  initialisation, the toolkit's policy (Nature CNN, MLP 256-256, orthogonal initialisation), or
  spatial-softmax keypoints of each frame (`KeypointNet`);
- `--state-aux C`: add C × the squared error of predicting the standardised state (x, ẋ, θ, θ̇)
  from the CNN's features, the state recorded beside the frames;
- `--differences`: feed the frame differences as extra planes;
- `--stride S`: stack every S-th frame, so that the stack spans (k − 1)·S steps;
- `--newest-diff`: feed only the newest frame and its difference from the oldest in the stack
  (with `--frames 2 --stride 2`: the frame 2 steps earlier);
- `--keyframe W`: weight W for samples at the expert's action changepoints (label ≠ previous
  label in the episode), 1 elsewhere (Wen et al. 2021); `--keyframe prior`: weight
  1 − p(label | previous label) from the training labels' counts, scaled to mean 1;
- `--cnn-lr LR`: a separate Adam learning rate for the CNN (convolutions and 512 features of
  `plain`, the image encoder of `library`, the convolutions of `keypoints`), `--lr` for the rest;
- `--history-dropout P`: in training, zero (after standardising) the older frames of each sample
  with probability P;
- `--adversary C`: a gradient-reversed head (×C) predicting the previous executed action (the sign
  of the recorded cart's velocity change) from the features and the current label (Wen et al.
  2020's conditional adversary against copycat);
- `--label-window K`: train on soft labels, the fraction of "right" among the expert's labels
  K steps either side in the same episode (the expert's chatter near upright averaged out);
- `--shift P`, `--shift-x P`: the random shift of the training frames (default 4), and a further
  sideways one (the clone made blind to where the cart is);
- `--crop T,L,H,W`: the recording's crop, for the rollouts;
- `--dagger-rounds R`: after BC, R rounds of DAgger: `--round-episodes` of the clone's own episodes
  labelled by the scripted expert on the recorded state, added to the training set, then
  `--round-steps` more Adam steps;
- `--threads N`: torch threads (default 1).

Each evaluation episode prints the state it ended in, and the summary the clone's agreement with
the expert's rule on its own states.

The last line printed, `summary`, gives held-out accuracy, mean return and training seconds.

Usage: python bench/pixels_cartpole_probe.py DEMOS.mcap [--scale standardised] [--seed 0] …
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np
import torch
from torch import nn

from imitation.data.loader import load_transitions
from imitation.encoders import random_shift
from imitation.envs.pixels import PixelRecipe, StackFrames, frame_stack_index, make_pixel_env
from imitation.experts.scripted import cartpole, cartpole_score
from imitation.policies import make_policy

CROP = "150,216,168,168"


def shift_columns(frames: torch.Tensor, pad: int) -> torch.Tensor:
    """Each sample of (batch, k, H, W, C) frames moved sideways by its own dx in {−pad, …, pad}, edges replicated."""
    if pad <= 0:
        return frames
    batch, width = frames.shape[0], frames.shape[3]
    dx = torch.randint(-pad, pad + 1, (batch,))
    columns = (torch.arange(width)[None] + dx[:, None]).clamp(0, width - 1)
    return torch.stack([sample[:, :, index] for sample, index in zip(frames, columns)])


class ReverseGradient(torch.autograd.Function):
    """Identity forward; the gradient times −scale backward (Ganin & Lempitsky 2015)."""

    @staticmethod
    def forward(ctx, x: torch.Tensor, scale: float) -> torch.Tensor:  # type: ignore[override]
        ctx.scale = scale
        return x.view_as(x)

    @staticmethod
    def backward(ctx, grad: torch.Tensor) -> tuple[torch.Tensor, None]:  # type: ignore[override]
        return -ctx.scale * grad, None


class PlainNet(nn.Module):
    """Nature CNN → 512 → 256 → 2 logits, with the 512 features kept for the auxiliary head."""

    def __init__(self, planes: int) -> None:
        super().__init__()
        self.convolutions = nn.Sequential(
            nn.Conv2d(planes, 32, 8, 4), nn.ReLU(), nn.Conv2d(32, 64, 4, 2), nn.ReLU(),
            nn.Conv2d(64, 64, 3, 1), nn.ReLU(), nn.Flatten(),
        )  # fmt: skip
        size = self.convolutions(torch.zeros(1, planes, 84, 84)).shape[1]
        self.features = nn.Sequential(nn.Linear(size, 512), nn.ReLU())
        self.head = nn.Sequential(nn.Linear(512, 256), nn.ReLU(), nn.Linear(256, 2))

    def forward(self, planes: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        features = self.features(self.convolutions(planes))
        return self.head(features), features


class KeypointNet(nn.Module):
    """Each frame through one small CNN ending in K feature maps, each map's spatial softmax
    reduced to its expected (x, y) (Levine et al. 2016; robomimic's encoder); the newest frame's
    keypoints and their differences from each older frame's (×20) go to a 256-256 head."""

    def __init__(self, frames: int, keypoints: int = 16) -> None:
        super().__init__()
        self.convolutions = nn.Sequential(
            nn.Conv2d(1, 16, 4, 2), nn.ReLU(), nn.Conv2d(16, 32, 3, 2), nn.ReLU(), nn.Conv2d(32, keypoints, 3, 1),
        )  # fmt: skip
        self.temperature = nn.Parameter(torch.ones(1))
        size = frames * 2 * keypoints
        self.head = nn.Sequential(nn.Linear(size, 256), nn.ReLU(), nn.Linear(256, 256), nn.ReLU(), nn.Linear(256, 2))

    def keypoints(self, planes: torch.Tensor) -> torch.Tensor:
        b, k, h, w = planes.shape
        maps = self.convolutions(planes.reshape(b * k, 1, h, w))
        _, c, mh, mw = maps.shape
        probabilities = torch.softmax(maps.reshape(b * k, c, mh * mw) / self.temperature, -1)
        ys, xs = torch.meshgrid(torch.linspace(-1, 1, mh), torch.linspace(-1, 1, mw), indexing="ij")
        points = torch.cat([probabilities @ xs.reshape(-1, 1), probabilities @ ys.reshape(-1, 1)], -1)
        return points.reshape(b, k, c * 2)

    def forward(self, planes: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        points = self.keypoints(planes)
        newest = points[:, -1]
        features = torch.cat([newest, *(20 * (newest - points[:, i]) for i in range(points.shape[1] - 1))], -1)
        return self.head(features), features


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("demos")
    parser.add_argument("--scale", choices=["raw", "standardised"], default="standardised")
    parser.add_argument("--head", choices=["plain", "library", "keypoints"], default="plain")
    parser.add_argument("--state-aux", type=float, default=0.0)
    parser.add_argument("--differences", action="store_true")
    parser.add_argument("--stride", type=int, default=1)
    parser.add_argument("--frames", type=int, default=4)
    parser.add_argument("--lr", type=float, default=3e-4)
    parser.add_argument("--newest-diff", action="store_true")
    parser.add_argument("--keyframe", default="", help="W (changepoint weight) or 'prior'")
    parser.add_argument("--cnn-lr", type=float, default=None)
    parser.add_argument("--history-dropout", type=float, default=0.0)
    parser.add_argument("--adversary", type=float, default=0.0)
    parser.add_argument("--label-window", type=int, default=0)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--steps", type=int, default=1500)
    parser.add_argument("--episodes", type=int, default=8, help="evaluation episodes")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--shift", type=int, default=4, help="random shift of the training frames (pixels)")
    parser.add_argument("--shift-x", type=int, default=0, help="a further horizontal shift of up to this many pixels")
    parser.add_argument(
        "--dagger-rounds", type=int, default=0, help="after BC: roll out, label with the expert, aggregate, train on"
    )
    parser.add_argument("--round-episodes", type=int, default=4)
    parser.add_argument("--round-steps", type=int, default=500)
    parser.add_argument("--crop", default=CROP, help="the recording's --crop, for the rollouts")
    args = parser.parse_args()
    torch.manual_seed(args.seed)
    torch.set_num_threads(args.threads)
    if (args.newest_diff or args.history_dropout) and args.head != "plain":
        parser.error("--newest-diff and --history-dropout need --head plain")

    data = load_transitions(args.demos, next_observations=False)
    span = (args.frames - 1) * args.stride + 1
    stacks = data.observations["pixels"][frame_stack_index(data.episode_index, span)[:, :: args.stride]]
    frames, labels = torch.as_tensor(stacks), torch.as_tensor(np.asarray(data.actions, dtype=np.int64))
    held_out = torch.as_tensor(np.isin(data.episode_index, np.unique(data.episode_index)[-4:]))
    state = torch.as_tensor(np.asarray(data.observations["state"], dtype=np.float32))
    state = (state - state[~held_out].mean(0)) / state[~held_out].std(0)
    sample = frames[~held_out][::7].float()
    mean, std = (sample.mean(), sample.std()) if args.scale == "standardised" else (torch.tensor(0.0), torch.tensor(255.0))

    # previous label within the episode (the first step's own label), changepoints, and the previous
    # executed action: the sign of the cart's velocity change from the step before (force dominates)
    actions = labels.numpy()
    starts = np.ones(len(actions), dtype=bool)
    starts[1:] = data.episode_index[1:] != data.episode_index[:-1]
    previous = np.where(starts, actions, np.roll(actions, 1))
    raw_state = np.asarray(data.observations["state"], dtype=np.float32)
    executed = torch.as_tensor(np.where(starts, actions, (raw_state[:, 1] > np.roll(raw_state[:, 1], 1)).astype(np.int64)))
    weights = torch.ones(len(actions))
    if args.keyframe == "prior":
        train = ~held_out.numpy()
        counts = np.ones((2, 2))
        np.add.at(counts, (previous[train], actions[train]), 1)
        conditional = counts / counts.sum(1, keepdims=True)
        weights = torch.as_tensor(1 - conditional[previous, actions], dtype=torch.float32)
        weights = weights / weights[~held_out].mean()
    elif args.keyframe:
        weights = torch.where(torch.as_tensor(actions != previous), float(args.keyframe), 1.0)
    targets = nn.functional.one_hot(labels, 2).float()
    if args.label_window:
        neighbours = np.arange(len(actions))[:, None] + np.arange(-args.label_window, args.label_window + 1)[None]
        inside = (neighbours >= 0) & (neighbours < len(actions))
        neighbours = np.clip(neighbours, 0, len(actions) - 1)
        inside &= data.episode_index[neighbours] == data.episode_index[:, None]
        right = (actions[neighbours] * inside).sum(1) / inside.sum(1)
        targets = torch.as_tensor(np.stack([1 - right, right], 1), dtype=torch.float32)
    changepoints = float((actions != previous)[~held_out.numpy()].mean())
    copied = float((executed.numpy() == previous).mean())
    print(f"changepoints {changepoints:.3f} of training labels; executed = previous label {copied:.3f}")

    def planes(batch: torch.Tensor, drop: float = 0.0) -> torch.Tensor:
        b, k, h, w, c = batch.shape
        x = (batch.permute(0, 1, 4, 2, 3).reshape(b, k * c, h, w).float() - mean) / std
        if drop:
            keep = (torch.rand(b, 1, 1, 1) >= drop).float()
            x = torch.cat([x[:, :-c] * keep, x[:, -c:]], 1)
        if args.newest_diff:
            return torch.cat([x[:, -c:], 5 * (x[:, -c:] - x[:, :c])], 1)
        return torch.cat([x, 5 * (x[:, 1:] - x[:, :-1])], 1) if args.differences else x

    if args.head == "library":
        space = gym.spaces.Dict({"pixels": gym.spaces.Box(0, 255, tuple(frames.shape[1:]), np.uint8)})
        policy = make_policy(
            space, gym.spaces.Discrete(2), frame_stack=args.frames, observation_keys=["pixels"],
            hidden_sizes=[256, 256], activation="relu", normalize_observations=args.scale == "standardised",
        )  # fmt: skip
        policy.update_normalizer({"pixels": frames[~held_out]})
        auxiliary = nn.Linear(policy.image_encoders[0].features, 4)

        def forward(batch: torch.Tensor, drop: float = 0.0) -> tuple[torch.Tensor, torch.Tensor]:
            features = policy.encode({"pixels": batch})
            return policy.distribution(features).logits, features

        parameters = [*policy.parameters(), *auxiliary.parameters()]
        cnn = list(policy.image_encoders.parameters())
    else:
        net = PlainNet(planes(frames[:1]).shape[1]) if args.head == "plain" else KeypointNet(args.frames)
        auxiliary = nn.Linear(512 if args.head == "plain" else 2 * 16 * args.frames, 4)

        def forward(batch: torch.Tensor, drop: float = 0.0) -> tuple[torch.Tensor, torch.Tensor]:
            return net(planes(batch, drop))

        parameters = [*net.parameters(), *auxiliary.parameters()]
        cnn = [*net.convolutions.parameters(), *(net.features.parameters() if args.head == "plain" else [])]
    width = auxiliary.in_features
    adversary = nn.Sequential(nn.Linear(width + 2, 64), nn.ReLU(), nn.Linear(64, 2))
    parameters = [*parameters, *adversary.parameters()]
    if args.cnn_lr is None:
        optimiser = torch.optim.Adam(parameters, lr=args.lr)
    else:
        ids = {id(p) for p in cnn}
        rest = [p for p in parameters if id(p) not in ids]
        optimiser = torch.optim.Adam([{"params": cnn, "lr": args.cnn_lr}, {"params": rest, "lr": args.lr}])
    rows, rng = np.flatnonzero(~held_out.numpy()), np.random.default_rng(args.seed)

    def held_out_fit() -> tuple[float, float]:
        with torch.no_grad():
            index = torch.nonzero(held_out).reshape(-1)
            logits = torch.cat([forward(frames[index[i : i + 512]])[0] for i in range(0, len(index), 512)])
            accuracy = (logits.argmax(1) == labels[index]).float().mean()
            return float(nn.functional.cross_entropy(logits, labels[index])), float(accuracy)

    started = time.perf_counter()

    def train(steps: int) -> None:
        for step in range(1, steps + 1):
            batch = rng.choice(rows, 128)
            logits, features = forward(
                shift_columns(random_shift(frames[batch], args.shift), args.shift_x), args.history_dropout
            )
            loss = (nn.functional.cross_entropy(logits, targets[batch], reduction="none") * weights[batch]).mean()
            if args.adversary:
                reversed_features = ReverseGradient.apply(features, args.adversary)
                guess = adversary(torch.cat([reversed_features, nn.functional.one_hot(labels[batch], 2).float()], 1))
                loss = loss + nn.functional.cross_entropy(guess, executed[batch])
            if args.state_aux:
                loss = loss + args.state_aux * ((auxiliary(features) - state[batch]) ** 2).mean()
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            if step % 500 == 0:
                nll, accuracy = held_out_fit()
                seconds = time.perf_counter() - started
                print(f"step {step}: held-out NLL {nll:.3f}, accuracy {accuracy:.3f} ({seconds:.0f} s)", flush=True)

    env = StackFrames(make_pixel_env("CartPole-v1", PixelRecipe.parse("84x84", grayscale=True, crop=args.crop)), span)

    def rollout(seeds: range, collect: bool) -> tuple[list[float], list[tuple[bool, bool, int]], list[np.ndarray], list[int]]:
        """The clone's deterministic episodes; with `collect`, its frame stacks and the expert's labels."""
        returns, agreement, visited, expert_labels = [], [], [], []
        for episode_seed in seeds:
            observation, _ = env.reset(seed=episode_seed)
            total, done = 0.0, False
            while not done:
                stack = observation["pixels"][:: args.stride]
                with torch.no_grad():
                    action = int(forward(torch.as_tensor(stack[None]))[0].argmax())
                state = np.asarray(env.unwrapped.state, dtype=np.float64)
                label, score = cartpole(state), cartpole_score(state)
                agreement.append((action == label, abs(score) > 1.0, action))
                if collect:
                    visited.append(np.array(stack))
                    expert_labels.append(label)
                observation, reward, terminated, truncated, _ = env.step(action)
                total, done = total + float(reward), terminated or truncated
            returns.append(total)
            if not collect:
                print(
                    f"episode {episode_seed}: {total:.0f}, end state {np.round(np.asarray(env.unwrapped.state), 3).tolist()}"
                )
        return returns, agreement, visited, expert_labels

    train(args.steps)
    for round_ in range(args.dagger_rounds):
        round_returns, _, visited, expert_labels = rollout(
            range(9000 + 100 * round_, 9000 + 100 * round_ + args.round_episodes), True
        )
        new = torch.as_tensor(np.stack(visited))
        first = len(frames)
        frames = torch.cat([frames, new])
        labels = torch.cat([labels, torch.as_tensor(expert_labels)])
        targets = torch.cat([targets, nn.functional.one_hot(torch.as_tensor(expert_labels), 2).float()])
        weights = torch.cat([weights, torch.ones(len(new))])
        held_out = torch.cat([held_out, torch.zeros(len(new), dtype=torch.bool)])
        rows = np.concatenate([rows, np.arange(first, len(frames))])
        print(
            f"DAgger round {round_ + 1}: the clone's returns {round_returns}, {len(new)} labels added ({len(rows)} in all)",
            flush=True,
        )
        train(args.round_steps)
    train_seconds = time.perf_counter() - started
    nll, accuracy = held_out_fit()
    returns, agreement, _, _ = rollout(range(5000, 5000 + args.episodes), False)
    print(f"returns {returns}: mean {np.mean(returns):.1f}")
    agrees, decisive, actions = (np.array(column) for column in zip(*agreement))
    print(
        f"on its own states: agrees with the expert {agrees.mean():.3f}, where |score| > 1 {agrees[decisive].mean():.3f}"
        f" ({decisive.mean():.3f} of steps); pushes right {actions.mean():.3f}"
    )
    print(f"summary: accuracy {accuracy:.3f}, NLL {nll:.3f}, return {np.mean(returns):.1f}, train {train_seconds:.0f} s")


if __name__ == "__main__":
    main()
