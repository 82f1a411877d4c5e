"""Peer side of issue 53's PushT comparison: LeRobot's own DiffusionPolicy (or ACTPolicy), trained on the CPU for a
wall-clock budget on the state-based PushT human demos, then scored closed-loop in gym_pusht/PushT-v0.

Everything LeRobot does is done through lerobot's own API (the installed version, 0.6.1 when written):

1. The zarr replay buffer (`data/state` agent x, y, block x, y, angle; `data/action` target agent
   position; `meta/episode_ends`) is written as a LeRobot dataset with `LeRobotDataset.create`,
   `add_frame`, `save_episode` and `finalize` under --work, at 10 fps: `observation.state` = agent x, y,
   `observation.environment_state` = the 5-number state (DiffusionConfig.validate_features wants an
   environment state or an image), `action` = the target position.
2. `DiffusionPolicy` is trained as `lerobot/scripts/lerobot_train.py` trains one policy on the CPU:
   `delta_timestamps` resolved from the config, `EpisodeAwareSampler` (shuffled, seeded, dropping the
   config's `drop_n_last_frames`), `make_pre_post_processors` with the dataset's stats (min-max
   normalisation), the config's optimizer and LR-scheduler presets, gradient clipping at the optimizer
   preset's `grad_clip_norm`, until --budget-minutes of training wall clock (data loading included)
   have passed (the step under way then finishes). The cosine schedule runs over --schedule-steps, as
   lerobot-train's over `--steps`. final_loss is the mean loss of the last 100 steps.
   lerobot-train's Accelerator is left out: it is a no-op for one process on the CPU in float32, and
   accelerate is not installed here.
3. Episode i is reset with seed --eval-seed + i in `gym_pusht/PushT-v0` with obs_type="state" (the
   5-number observation); `policy.reset()` at its start, then each step LeRobot's preprocessor,
   `select_action` (its own observation and action queues) and postprocessor, as lerobot-eval does,
   for at most 300 steps. torch's seed is set to the episode's seed too, so an episode's denoising
   noise is reproducible. An episode scores the maximum of `info["coverage"]` and whether
   `info["is_success"]` was ever true.

Presets (--preset); the diffusion ones with LeRobot's PushT training settings (batch 64, Adam lr 1e-4, betas 0.95,
0.999, eps 1e-8, weight decay 1e-6, grad-clip norm 10, cosine schedule with 500 warm-up steps over
200,000 steps, no EMA: LeRobot dropped it, huggingface/lerobot#134) and n_obs_steps 2, horizon 16, n_action_steps 8:
  pusht: DiffusionConfig's defaults otherwise, as the lerobot/diffusion_pusht card: U-Net down_dims
    (512, 1024, 2048), DDPM with 100 training steps and 100 inference steps.
  pusht_keypoints: LeRobot's own state-based PushT config (its former hydra file
    lerobot/configs/policy/diffusion_pusht_keypoints.yaml): down_dims (256, 512, 1024), DDIM, 10
    inference steps.
  act: ACTPolicy with ACTConfig's defaults (LeRobot has no PushT ACT config: dim_model 512, 4 encoder
    layers, 1 decoder layer, the CVAE with KL weight 10, AdamW lr 1e-5, weight decay 1e-4, no LR
    schedule) but the other heads' windows: a chunk of 16 actions, 8 executed before planning again
    (its default 100 is 10 s of PushT); with --ensemble M it plans every step and executes ACT's
    temporal ensemble with coefficient M instead. ACT reads one observation (n_obs_steps 1). Train it
    with --batch-size 8, ACT's own.

Nothing reaches the Hugging Face hub: HF_HUB_OFFLINE=1 and a fresh HF_HOME are set before lerobot is
imported, and the dataset is always opened by `root`. Progress goes to stderr; stdout gets one JSON line.

    nice -n 10 .venv/bin/python bench/pusht_lerobot.py --budget-minutes 30 --episodes 50 --threads 2
"""

from __future__ import annotations

import argparse
import atexit
import json
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

# Before lerobot (and huggingface_hub, which reads these once) is imported: nothing may reach the hub,
# and no cache of the user's may be read or written.
_HF_HOME = tempfile.mkdtemp(prefix="pusht_lerobot_hf_")
atexit.register(shutil.rmtree, _HF_HOME, ignore_errors=True)
os.environ["HF_HOME"] = _HF_HOME
os.environ["HF_HUB_OFFLINE"] = "1"
os.environ["HF_DATASETS_OFFLINE"] = "1"
os.environ["HF_DATASETS_DISABLE_PROGRESS_BARS"] = "1"  # else one bar per saved episode

import gym_pusht  # noqa: E402, F401  (registers gym_pusht/PushT-v0)
import gymnasium as gym  # noqa: E402
import lerobot  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
import zarr  # noqa: E402
from lerobot.configs.policies import PreTrainedConfig  # noqa: E402
from lerobot.datasets import EpisodeAwareSampler, LeRobotDataset, LeRobotDatasetMetadata  # noqa: E402
from lerobot.datasets.factory import resolve_delta_timestamps  # noqa: E402
from lerobot.policies import PreTrainedPolicy, make_policy, make_pre_post_processors  # noqa: E402
from lerobot.policies.act.configuration_act import ACTConfig  # noqa: E402
from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig  # noqa: E402
from lerobot.utils.random_utils import set_seed  # noqa: E402
from lerobot.utils.utils import cycle  # noqa: E402

DEMOS = Path("/work/shared/testdata/manipulation/pusht/pusht_cchi_v7_replay.zarr")
REPO_ID = "local/pusht_state"  # a name only: the dataset lives under --work and is opened by root
FPS = 10
TASK = "Push the T-shaped block onto the T-shaped target."
# No videos are written or read; naming a backend spares lerobot its probe of torchcodec, which cannot
# load here (no FFmpeg 4 libraries) and logs a traceback at every dataset it opens.
VIDEO_BACKEND = "pyav"
MAX_STEPS = 300  # gym_pusht's episode limit
SCHEDULE_STEPS = 200_000  # the PushT configs' `offline_steps` / lerobot-train's `--steps`
PROGRESS_SECONDS = 15.0
FINAL_LOSS_STEPS = 100  # one batch's diffusion loss is noisy: the last steps' mean is reported
FEATURES = {
    "observation.state": {"dtype": "float32", "shape": (2,), "names": ["agent_x", "agent_y"]},
    "observation.environment_state": {
        "dtype": "float32",
        "shape": (5,),
        "names": ["agent_x", "agent_y", "block_x", "block_y", "block_angle"],
    },
    "action": {"dtype": "float32", "shape": (2,), "names": ["target_x", "target_y"]},
}
DIFFUSION_WINDOWS = {"n_obs_steps": 2, "horizon": 16, "n_action_steps": 8}
PRESETS: dict[str, tuple[type[PreTrainedConfig], dict[str, Any]]] = {
    "pusht": (DiffusionConfig, DIFFUSION_WINDOWS),
    "pusht_keypoints": (
        DiffusionConfig,
        {**DIFFUSION_WINDOWS, "down_dims": (256, 512, 1024), "noise_scheduler_type": "DDIM", "num_inference_steps": 10},
    ),
    "act": (ACTConfig, {"chunk_size": 16, "n_action_steps": 8}),
}


@dataclass
class Training:
    steps: int
    samples: int
    final_loss: float
    seconds: float


@dataclass
class Evaluation:
    max_coverage: list[float]
    success: list[bool]
    seconds_per_action: float
    seconds: float


def progress(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def read_demos(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(state (N, 5), action (N, 2), episode_ends) of a Diffusion Policy PushT replay buffer."""
    group = zarr.open_group(str(path), mode="r")
    state = np.asarray(group["data/state"], dtype=np.float32)
    action = np.asarray(group["data/action"], dtype=np.float32)
    ends = np.asarray(group["meta/episode_ends"], dtype=np.int64)
    if state.shape[1:] != (5,) or action.shape != (len(state), 2) or len(ends) == 0 or ends[-1] != len(state):
        raise SystemExit(f"{path}: want data/state (N, 5), data/action (N, 2), meta/episode_ends ending at N")
    return state, action, ends


def write_dataset(demos: Path, root: Path) -> int:
    """The demos as a LeRobot dataset at root, through lerobot's writer; returns the episode count."""
    state, action, ends = read_demos(demos)
    dataset = LeRobotDataset.create(
        repo_id=REPO_ID, fps=FPS, features=FEATURES, root=root, use_videos=False, video_backend=VIDEO_BACKEND
    )
    start = 0
    for end in ends:
        for row in range(start, end):
            dataset.add_frame(
                {
                    "observation.state": state[row, :2],
                    "observation.environment_state": state[row],
                    "action": action[row],
                    "task": TASK,
                }
            )
        dataset.save_episode()
        start = end
    dataset.finalize()
    return len(ends)


def make_config(preset: str, ensemble: float | None) -> PreTrainedConfig:
    kind, settings = PRESETS[preset]
    if ensemble is not None:
        settings = {**settings, "n_action_steps": 1, "temporal_ensemble_coeff": ensemble}
    return kind(device="cpu", push_to_hub=False, **settings)


def batches(dataset: LeRobotDataset, config: PreTrainedConfig, batch_size: int, seed: int) -> Iterator[dict]:
    """lerobot-train's data order: EpisodeAwareSampler over every episode, cycled."""
    sampler = EpisodeAwareSampler(
        dataset.meta.episodes["dataset_from_index"],
        dataset.meta.episodes["dataset_to_index"],
        episode_indices_to_use=dataset.episodes,
        drop_n_last_frames=getattr(config, "drop_n_last_frames", 0),  # as lerobot-train: ACT has none
        shuffle=True,
        seed=seed,
        absolute_to_relative_idx=dataset.absolute_to_relative_idx,
    )
    loader = torch.utils.data.DataLoader(dataset, batch_size=batch_size, sampler=sampler, num_workers=0)
    return cycle(loader)


def train(
    policy: PreTrainedPolicy,
    preprocessor: Any,
    data: Iterator[dict],
    config: PreTrainedConfig,
    budget_seconds: float,
    schedule_steps: int,
) -> Training:
    """lerobot-train's update_policy, step after step, until the budget is spent."""
    optimizer_config = config.get_optimizer_preset()
    optimizer = optimizer_config.build(policy.get_optim_params())
    schedule = config.get_scheduler_preset()  # None for ACT: a constant learning rate
    scheduler = schedule.build(optimizer, schedule_steps) if schedule is not None else None
    policy.train()
    losses: list[float] = []
    samples = 0
    start = last_report = time.perf_counter()
    while time.perf_counter() - start < budget_seconds:
        batch = preprocessor(next(data))
        loss, _ = policy.forward(batch)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(policy.parameters(), optimizer_config.grad_clip_norm)
        optimizer.step()
        optimizer.zero_grad()
        if scheduler is not None:
            scheduler.step()
        losses.append(loss.item())
        samples += len(batch["action"])
        now = time.perf_counter()
        if now - last_report >= PROGRESS_SECONDS:
            progress(
                f"step {len(losses)} loss {losses[-1]:.4f} lr {optimizer.param_groups[0]['lr']:.2e} elapsed {now - start:.0f}s"
            )
            last_report = now
    seconds = time.perf_counter() - start
    final_loss = float(np.mean(losses[-FINAL_LOSS_STEPS:])) if losses else float("nan")
    return Training(steps=len(losses), samples=samples, final_loss=final_loss, seconds=seconds)


def observation_batch(obs: np.ndarray) -> dict[str, torch.Tensor]:
    """LeRobot's batch of one from PushT's state observation, as lerobot-eval's preprocess_observation."""
    observation = torch.as_tensor(obs, dtype=torch.float32).unsqueeze(0)
    return {"observation.state": observation[:, :2], "observation.environment_state": observation}


def evaluate(policy: PreTrainedPolicy, preprocessor: Any, postprocessor: Any, episodes: int, eval_seed: int) -> Evaluation:
    """Closed-loop episodes in gym_pusht/PushT-v0 (obs_type="state"), episode i seeded eval_seed + i."""
    env = gym.make("gym_pusht/PushT-v0", obs_type="state", max_episode_steps=MAX_STEPS)
    policy.eval()
    max_coverage: list[float] = []
    success: list[bool] = []
    policy_seconds, actions = 0.0, 0
    start = time.perf_counter()
    for episode in range(episodes):
        seed = eval_seed + episode
        torch.manual_seed(seed)
        obs, _ = env.reset(seed=seed)
        policy.reset()
        coverage, succeeded, done = 0.0, False, False
        while not done:
            tick = time.perf_counter()
            with torch.inference_mode():
                action = postprocessor(policy.select_action(preprocessor(observation_batch(obs))))
            policy_seconds += time.perf_counter() - tick
            actions += 1
            obs, _, terminated, truncated, info = env.step(action[0].numpy())
            coverage = max(coverage, float(info["coverage"]))
            succeeded = succeeded or bool(info["is_success"])
            done = terminated or truncated
        max_coverage.append(coverage)
        success.append(succeeded)
        progress(f"episode {episode} seed {seed}: max coverage {coverage:.3f} success {succeeded}")
    env.close()
    return Evaluation(
        max_coverage=max_coverage,
        success=success,
        seconds_per_action=policy_seconds / max(actions, 1),
        seconds=time.perf_counter() - start,
    )


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--budget-minutes", type=float, required=True, help="training wall clock")
    parser.add_argument("--episodes", type=int, default=50, help="evaluation episodes (default 50)")
    parser.add_argument("--eval-seed", type=int, default=10000, help="episode i is reset with this + i")
    parser.add_argument("--seed", type=int, default=0, help="python/numpy/torch seed and the sampler's")
    parser.add_argument("--threads", type=int, default=2, help="torch.set_num_threads (default 2)")
    parser.add_argument("--batch-size", type=int, default=64, help="default 64, LeRobot's PushT batch")
    parser.add_argument("--preset", choices=sorted(PRESETS), default="pusht", help="see the module docstring")
    parser.add_argument("--ensemble", type=float, default=None, help="act: temporal ensembling with this coefficient")
    parser.add_argument("--schedule-steps", type=int, default=SCHEDULE_STEPS, help="steps the cosine LR schedule spans")
    parser.add_argument("--demos", type=Path, default=DEMOS, help="the PushT zarr replay buffer")
    parser.add_argument(
        "--work", type=Path, default=None, help="folder the LeRobot dataset is written into (default: new, in /tmp)"
    )
    args = parser.parse_args()
    if args.budget_minutes <= 0 or args.episodes < 0 or args.threads < 1 or args.batch_size < 1:
        parser.error("--budget-minutes, --threads and --batch-size must be positive, --episodes ≥ 0")
    if args.work is None:
        args.work = Path(tempfile.mkdtemp(prefix="pusht_lerobot_"))
    if (args.work / "pusht_state").exists():
        parser.error(f"{args.work / 'pusht_state'} exists: give a --work folder without a dataset in it")
    return args


def main() -> None:
    args = parse_args()
    torch.set_num_threads(args.threads)
    root = args.work / "pusht_state"

    tick = time.perf_counter()
    episodes = write_dataset(args.demos, root)
    dataset_seconds = time.perf_counter() - tick
    progress(f"wrote {episodes} episodes to {root} in {dataset_seconds:.1f}s")

    set_seed(args.seed)
    if args.ensemble is not None and args.preset != "act":
        raise SystemExit("--ensemble is ACT's temporal ensembling: use it with --preset act")
    config = make_config(args.preset, args.ensemble)
    meta = LeRobotDatasetMetadata(REPO_ID, root=root)
    delta_timestamps = resolve_delta_timestamps(config, meta)
    dataset = LeRobotDataset(REPO_ID, root=root, delta_timestamps=delta_timestamps, video_backend=VIDEO_BACKEND)
    policy = make_policy(config, ds_meta=dataset.meta)
    preprocessor, postprocessor = make_pre_post_processors(config, dataset_stats=dataset.meta.stats)
    progress(f"{sum(p.numel() for p in policy.parameters()):,} parameters; training {args.budget_minutes} min")

    data = batches(dataset, config, args.batch_size, args.seed)
    training = train(policy, preprocessor, data, config, args.budget_minutes * 60, args.schedule_steps)
    evaluation = evaluate(policy, preprocessor, postprocessor, args.episodes, args.eval_seed)

    result = {
        "peer": f"lerobot {lerobot.__version__} {type(policy).__name__}",
        "preset": args.preset,
        "ensemble": args.ensemble,
        "budget_minutes": args.budget_minutes,
        "train_steps": training.steps,
        "samples": training.samples,
        "final_loss": training.final_loss,
        "seed": args.seed,
        "batch_size": args.batch_size,
        "threads": args.threads,
        "mean_max_coverage": float(np.mean(evaluation.max_coverage)) if args.episodes else None,
        "success_rate": float(np.mean(evaluation.success)) if args.episodes else None,
        "episode_coverage": evaluation.max_coverage,
        "seconds_per_action": evaluation.seconds_per_action,
        "dataset_seconds": dataset_seconds,
        "train_seconds": training.seconds,
        "eval_seconds": evaluation.seconds,
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
