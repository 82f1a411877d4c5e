"""The command line, declared: each command's words, help and description, and the dataclasses
its flags come from (imitation/flags.py): the learners' and jobs' configs, whose flags a user may
leave out so that a default or a preset applies, and the commands' own options below. The
`train` commands are declared in their table, imitation/train_commands.py, with their learners;
cli.py builds the parser from both and holds one handler per other command.

Light, like the configs: `imitation --help` reads this module without importing torch.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from imitation.data.convert.sources import SOURCES
from imitation.data.export.formats import FORMATS
from imitation.flags import flag, quality, seconds, speed
from imitation.jobs.evaluate_policy_config import PolicyEvaluationConfig
from imitation.jobs.evaluate_reward_config import RewardEvaluationConfig
from imitation.jobs.irl_methods import DEFAULT_METHOD, IRL_METHODS
from imitation.jobs.record_config import COMPRESSIONS, IMAGE_CODECS, RecordConfig

ENV_ID = "gymnasium environment id"
DEMO_FILES = "F.mcap"
# Helps whose subject each command names (`Options(..., helps=pixels_helps(...))`).
PIXELS_HELP = (
    "observations {what} rendered frames resized to H×W (e.g. 84x84) under the key 'pixels', with the env's own "
    "observation beside them as 'state' (the expert acts on the state)"
)
WORKERS_HELP = "run {what} on N Ray workers (pip install 'imitation-mcap[ray]')"


# ------------------------------------------------------------------------------------------------
# Options several commands share.


@dataclass(kw_only=True)
class Global:
    limit: list[str] = flag(
        append=True,
        default_factory=list,
        metavar="NAME=N",
        help="raise a resource bound for this run, e.g. --limit sample_elements=33554432 (bounds: sample_elements, "
        "dict_leaves, expansion_ratio, chunk_bytes, yaml_nodes, policy_parameters, grid_steps_per_message, "
        "remote_stall_seconds, remote_request_seconds, remote_total_seconds, remote_request_bytes; see imitation/limits.py)",
        default_text="none",
    )


@dataclass(kw_only=True)
class Json:
    json: bool = flag(False, help="print one JSON object with the results")


@dataclass(kw_only=True)
class Quiet:
    quiet: bool = flag(False, help="no progress bar")


@dataclass(kw_only=True)
class RunOutput:
    """Every `train` command: the run directory, and how it reports."""

    out: str = flag(metavar="RUN_DIR", help="run directory to write (replaced only when the run completes)")
    json: bool = flag(False, help="print one JSON object with the results")
    quiet: bool = flag(False, help="no progress bar")
    resume: bool = flag(
        False,
        help="continue the interrupted run in RUN_DIR.partial from its last checkpoint (saved every tenth of the run, after "
        "its last step and on Ctrl-C), with the same settings, to the same total",
    )


@dataclass(kw_only=True)
class Pixels:
    """Rendered frames as observations: `helps["pixels"]` says, per command, what sees them."""

    pixels: str | None = flag(
        None, metavar="HxW", help=PIXELS_HELP.format(what="are"), default_text="the env's own observations"
    )
    grayscale: bool = flag(False, help="with --pixels: one luma channel instead of RGB")
    crop: str | None = flag(
        None,
        metavar="T,L,H,W",
        help="with --pixels: keep only this rectangle of the rendered image (top, left, height, width in pixels) "
        "before resizing, e.g. 150,200,180,200 around CartPole's cart and pole in its 400×600 frame",
        default_text="the whole image",
    )


@dataclass(kw_only=True)
class PersonSpeed:
    speed: float = flag(
        1.0,
        parse=speed,
        metavar="X",
        help="with --expert keyboard, gamepad or pointer: the window runs at X times real time, from 0.125 to 4",
    )


@dataclass(kw_only=True)
class RayWorkers:
    """`helps["workers"]` says, per command, what runs on the workers."""

    workers: int | None = flag(
        None, metavar="N", help=WORKERS_HELP.format(what="the work"), default_text="in this process, no Ray"
    )
    ray_address: str = flag(
        "local",
        metavar="ADDR|auto|local",
        help="with --workers: the Ray cluster to use; 'local' starts one on this machine for the run",
    )
    cpus: int | None = flag(
        None, metavar="C", help="with --workers and a local Ray: the CPUs it may use", default_text="every core"
    )


def workers_helps(what: str) -> dict[str, str]:
    return {"workers": WORKERS_HELP.format(what=what)}


def pixels_helps(what: str) -> dict[str, str]:
    return {"pixels": PIXELS_HELP.format(what=what)}


# ------------------------------------------------------------------------------------------------
# Each command's own options.


@dataclass(kw_only=True)
class RecordOptions:
    out: str = flag(metavar=DEMO_FILES, help="output demo file")


@dataclass(kw_only=True)
class InfoOptions:
    file: str = flag(positional=True, metavar=DEMO_FILES, help="demo file, or a DAgger run directory: one line per round")


@dataclass(kw_only=True)
class RecoverOptions:
    partial: str = flag(positional=True, metavar="F.mcap.partial", help="the partial demo file")
    out: str | None = flag(
        None,
        metavar=DEMO_FILES,
        help="the recovered file, which must not exist",
        default_text="the partial file's name without .partial",
    )
    compression: str = flag("lz4", choices=COMPRESSIONS, help="chunk compression")


@dataclass(kw_only=True)
class ConvertOptions:
    source: str = flag(
        positional=True,
        metavar="SRC",
        help="a .mcap bag or rosbag2 folder, a ROS 1 .bag, a LeRobot dataset root, a zarr replay buffer, an .npz file, "
        "or a .npy array",
    )
    source_kind: str | None = flag(
        None, name="--from", metavar="KIND", help=", ".join(SOURCES), default_text="recognised from SRC"
    )
    map: str | None = flag(
        None,
        metavar="MAP.yaml",
        help="for bags: which topics and fields form the observation and the action",
        default_text="none",
    )
    layout: str | None = flag(
        None,
        metavar="LAYOUT.yaml",
        help="for bare arrays (.npy, or an npz member) of shape (episodes, steps, columns): which columns are observation "
        "and action, what rows hold, the padding, the reward, how episodes end (see docs/CONVERT.md)",
        default_text="none",
    )
    out: str | None = flag(
        None, metavar=DEMO_FILES, help="output demo file (written atomically)", default_text="none: give it, or --inspect"
    )
    env: str | None = flag(
        None,
        metavar="ID",
        help="gymnasium id the demos belong to: its spaces are used (overrides the map's env_id)",
        default_text="the map's, else none",
    )
    inspect: bool = flag(False, help="list a bag's topics, types, counts, rates and numeric fields; convert nothing")
    write_map: str | None = flag(
        None,
        metavar="MAP.yaml",
        help="with --inspect: also write a starter map to edit (it steps at the command's rate, leaves out observations "
        "slower than one value per 10 steps, and takes a laser's ranges with nonfinite: range_max)",
        default_text="none",
    )
    image_codec: str = flag(
        "png",
        choices=IMAGE_CODECS,
        help="how camera frames are stored: png (lossless), jpeg (lossy, quality 95), webp (lossy, quality 85; colour "
        "frames only) or raw (lossless, chunk-compressed). Measured on LeRobot's AV1 videos of 224x224 cameras, the "
        "demo file takes 13.8 times the videos' bytes as png, 5.5 as jpeg, 1.7 as webp (45 dB PSNR). A bag's JPEG or "
        "PNG frames, and a LeRobot image feature's, are stored as they are when the codec is theirs and they are not "
        "resized; video frames are decoded and encoded again",
    )
    image_quality: int | None = flag(
        None,
        parse=quality,
        metavar="Q",
        help="quality of --image-codec jpeg or webp, 1 to 100",
        default_text="95 for jpeg, 85 for webp",
    )
    image_size: str | None = flag(
        None,
        metavar="HxW",
        help="resize every camera's frames to H×W (area averaging) as they convert, e.g. 96x96; a bag's map entry may "
        "give its own resize: [H, W]; the frames' own size is kept in the file's metadata",
        default_text="as recorded",
    )
    video_tolerance: float | None = flag(
        None,
        parse=seconds,
        metavar="S",
        help="LeRobot videos: find each row's frame by its timestamp, within S seconds",
        default_text="by timestamp within 1e-4 s, lerobot's tolerance, or by frame_index where the timestamps stray "
        "further, as a wall clock's do",
    )
    ros_distro: str = flag(
        "latest",
        metavar="NAME",
        help="message definitions for rosbag2 sqlite bags that carry none (recorded before Iron): foxy, humble, ...",
    )


@dataclass(kw_only=True)
class ExportOptions:
    file: str = flag(positional=True, metavar=DEMO_FILES, help="demo file")
    to: list[str] = flag(
        nargs=2,
        metavar=("FORMAT", "DEST"),
        help=", or ".join(f"{known.name} {known.destination}" for known in FORMATS.values()),
    )


@dataclass(kw_only=True)
class PPOOptions:
    reward: str | None = flag(
        None,
        metavar="RUN_DIR",
        help="optimise this reward model instead of the env's reward (true returns are still logged); a pixel reward's "
        "frames are rendered as it was learnt on them",
        default_text="the env's reward",
    )
    shaped: bool = flag(
        False,
        help="with --reward of an AIRL run: optimise f = g + γh(s') − h(s), its reward g shaped by the potential h it "
        "learnt (the same optimal policies as g)",
    )


@dataclass(kw_only=True)
class BCOptions:
    demos: list[str] = flag(nargs="+", metavar=DEMO_FILES, help="one or more demo files of the same env")
    env: str | None = flag(
        None,
        metavar="ID",
        help="gymnasium environment id (for spaces and evaluation); without it BC trains offline on the demos' own "
        "spaces and reports the validation loss only",
        default_text="none: offline",
    )


@dataclass(kw_only=True)
class DAggerOptions:
    env: str = flag(metavar="ID", help=ENV_ID)
    expert: str = flag(
        metavar="SPEC",
        help="scripted, standin (a scripted person who takes over when the state turns risky; CartPole), keyboard "
        "(discrete actions), gamepad (continuous actions; arrow keys without one), pointer (a mouse; actions that are a "
        "point of the picture, as PushT's), a run directory, or sb3:ZIP",
    )
    demos: list[str] | None = flag(
        None,
        nargs="+",
        metavar=DEMO_FILES,
        help="expert demos to start from (they stand for the expert-only first round, so round 1 runs at the "
        "schedule's second β)",
        default_text="none",
    )


@dataclass(kw_only=True)
class IRLOptions:
    method: str = flag(DEFAULT_METHOD, choices=tuple(IRL_METHODS), help="the IRL algorithm")
    env: str = flag(metavar="ID", help=ENV_ID)
    demos: list[str] = flag(nargs="+", metavar=DEMO_FILES, help="expert demo files of that env")
    warm_start: str | None = flag(
        None,
        metavar="RUN_DIR",
        help="airl/gail: start the discriminator (AIRL's g and h, GAIL's D) from a finished run's of the same method "
        "and networks, the policy from scratch: its negatives then include the states a fresh policy passes through "
        "on that reward",
        default_text="a fresh discriminator",
    )


@dataclass(kw_only=True)
class EvalPolicyOptions:
    run: str = flag(positional=True, metavar="RUN_DIR", help="a PPO, BC or DAgger run directory")
    env: str = flag(metavar="ID", help=ENV_ID)


@dataclass(kw_only=True)
class EvalRewardOptions:
    run: str = flag(positional=True, metavar="RUN_DIR", help="a reward run directory (`train irl`)")
    env: str = flag(metavar="ID", help=ENV_ID)
    out: str | None = flag(None, metavar="DIR", help="where the evaluation goes", default_text="RUN_DIR/eval-reward")


@dataclass(kw_only=True)
class DemoOptions:
    out: str = flag("demo-output", metavar="DIR", help="output directory")
    datasets: str | None = flag(
        None, metavar="DIR", help="where the bundled datasets are", default_text="the repository's datasets/"
    )
    quick: bool = flag(False, help="a one-minute smoke run: every training cut short (its learning results mean nothing)")


@dataclass(kw_only=True)
class SweepOptions:
    config: str = flag(
        positional=True,
        metavar="CONFIG.yaml",
        help="the sweep: train command, fixed flags (args), search space (space), metric, search, trials, scheduler "
        "(docs/SCALING.md; an example: docs/sweeps/bc-cartpole.yaml)",
    )
    out: str | None = flag(
        None,
        metavar="DIR",
        help="the sweep's folder; give the same one to continue an interrupted sweep",
        default_text="sweeps/ and the config's name without .yaml",
    )
    ray_address: str = flag(
        "local",
        metavar="ADDR",
        help="local (a Ray started on this machine for the sweep), auto (the cluster this machine belongs to) or "
        "HOST:PORT; on a cluster DIR must be on storage every node shares",
    )
    cpus: int | None = flag(
        None,
        metavar="C",
        help="with a local Ray: the CPUs the trials share, each taking the config's cpus_per_trial",
        default_text="every core",
    )


# ------------------------------------------------------------------------------------------------
# The commands.


@dataclass(frozen=True)
class Options:
    """A dataclass whose flags a command takes, with how (imitation.flags.add_flags)."""

    config: type
    only: tuple[str, ...] | None = None
    label: str | None = None
    default_texts: Mapping[str, str] = field(default_factory=dict)
    helps: Mapping[str, str] = field(default_factory=dict)
    fill: bool = True  # a command's own options; a learner's or job's config is given with fill=False
    choices: Mapping[str, tuple[str, ...]] = field(default_factory=dict)


def settings(
    config: type,
    *,
    only: tuple[str, ...] | None = None,
    label: str | None = None,
    default_texts: Mapping[str, str] | None = None,
) -> Options:
    """A config's flags: left None when not given, for its default or a preset to apply."""
    return Options(config, only, label, default_texts or {}, fill=False)


@dataclass(frozen=True)
class Command:
    """`options` is a function for a command whose flags come from a registry read when the
    parser is built (`train irl`'s methods)."""

    help: str
    description: str
    options: tuple[Options, ...] | Callable[[], tuple[Options, ...]]


# Groups of subcommands (`train`, `eval`): their help, description, and the name of the argument
# that holds the subcommand.
GROUPS: dict[str, tuple[str, str, str]] = {
    "train": ("train a policy or reward model", "Train a policy or reward model into a run directory.", "algorithm"),
    "eval": ("evaluate a policy or a recovered reward", "Evaluate a trained policy or reward.", "target"),
}

COMMANDS: dict[str, Command] = {
    "record": Command(
        "record expert episodes of a gymnasium env into an MCAP demo file",
        "Run an expert in a gymnasium environment and write each finished episode to an MCAP demo file as it ends (while "
        "recording the file is named F.mcap.partial; Ctrl-C keeps the finished episodes).",
        (
            settings(RecordConfig),
            Options(RecordOptions),
            Options(Pixels, helps=pixels_helps("recorded as")),
            Options(PersonSpeed),
            Options(Json),
            Options(Quiet),
        ),
    ),
    "info": Command(
        "describe a demo file: episodes, returns, lengths, spaces, channels, damage",
        "Describe an MCAP demo file, or each round of a DAgger run directory, with how much a person drove (the "
        "intervention rate) where the file records it. Every chunk is checked; a damaged file is described by the "
        "complete episodes that can be salvaged and the command exits with code 1.",
        (Options(InfoOptions), Options(Json)),
    ),
    "recover": Command(
        "turn the F.mcap.partial of an interrupted or failed write into a demo file",
        "A writer that was killed, ran out of disk space or stopped on an error leaves F.mcap.partial with every episode "
        "it had finished. recover writes those episodes, bit-exact, to a new demo file (default: F.mcap), then removes the "
        "partial file unless more than its unfinished tail was damaged.",
        (Options(RecoverOptions), Options(Json)),
    ),
    "convert": Command(
        "convert a ROS bag, a LeRobot dataset, a zarr replay buffer or npz rollouts into an MCAP demo file",
        "Convert recordings into an MCAP demo file. ROS bags (ROS 2 .mcap file or rosbag2 directory, ROS 1 .bag, rosbag2 "
        "sqlite directory) need a map (YAML: topics and fields for the observation and action, rate, alignment, episodes, "
        "what a laser's inf beams stand for; see docs/CONVERT.md); --inspect lists a bag's topics and numeric fields and "
        "--write-map writes a starter map. LeRobot datasets (v3.0, v2.1) and npz rollouts (stable-baselines GAIL, "
        "HumanCompatibleAI/imitation) convert without a map, and so do zarr replay buffers (the Diffusion Policy code's "
        "layout: PushT's human demos; with --env, the array that fits the env's observation); a bare (episodes, steps, "
        "columns) array needs a layout (--layout). Cameras become image observations: LeRobot video and image features, "
        "zarr frame arrays, and ROS image topics a map names with image:, stored as --image-codec says and resized once "
        "by --image-size (or a map entry's resize:). "
        "With --env, end flags that the source cannot tell apart (a time limit or a terminal state) are decided from the "
        "env's time limit, or, for a layout with ends: terminal_state, where the env's own termination rule first holds "
        "on the recorded states (the steps after it are cut).",
        (Options(ConvertOptions), Options(Json), Options(Quiet)),
    ),
    "export": Command(
        "export a demo file as a LeRobotDataset v3.0 or a per-step MCAP Foxglove can plot",
        "Export an MCAP demo file: `--to lerobot DIR` writes a LeRobotDataset (codebase v3.0) that lerobot's "
        "LeRobotDataset loads; `--to foxglove F2.mcap` writes one JSON message per step, with a JSON schema, for "
        "plotting in Foxglove.",
        (Options(ExportOptions), Options(Json), Options(Quiet)),
    ),
    "eval policy": Command(
        "return of a run's policy",
        "Mean, std, min and max return of a run directory's policy.",
        (Options(EvalPolicyOptions), settings(PolicyEvaluationConfig), Options(Json)),
    ),
    "eval reward": Command(
        "is a recovered reward any good? EPIC, retraining and controls",
        "Judge a recovered reward three ways beside two controls (a constant reward and a random network): EPIC distance "
        "and Pearson correlation to the true reward (exact on tabular MDPs, sampled on continuous envs), and the true "
        "return of policies retrained from scratch on it (PPO for continuous envs, the exact soft-optimal policy on "
        "tabular ones), normalised between a random policy (0) and the demos (1). Writes metrics.json, plots and "
        "report.md to --out.",
        (
            Options(EvalRewardOptions),
            settings(RewardEvaluationConfig),
            Options(RayWorkers, helps=workers_helps("the retrainings as Ray tasks (instead of --jobs local processes)")),
            Options(Json),
            Options(Quiet),
        ),
    ),
    "demo": Command(
        "the whole chain on the bundled data, with one report",
        "Bundled demos → behavioural cloning and DAgger (CartPole-v1) → MaxEnt IRL on a gridworld and guided cost "
        "learning on fixed-horizon CartPole → PPO from scratch on the recovered reward → eval policy and eval reward, "
        "offline, in about three minutes on 2 cores; writes DIR/report.md with every result and plot.",
        (Options(DemoOptions), Options(Json), Options(Quiet)),
    ),
    "sweep": Command(
        "hyperparameter sweep over a train command's flags with Ray Tune (random or Optuna search, ASHA)",
        "Run a train command many times with flags drawn from a search space (random search or Optuna), each trial in a "
        "Ray worker into its own run directory, stopping poor trials early with ASHA. Writes DIR/results.csv and "
        "DIR/results.md (one row per trial: flags, metric, steps run, how it ended, run directory) and DIR/best, a copy "
        "of the best finished trial's run directory. After Ctrl-C, the same command continues the sweep without running "
        "its finished trials again. Needs the optional extra: pip install 'imitation-mcap[ray]'.",
        (Options(SweepOptions), Options(Json)),
    ),
}
