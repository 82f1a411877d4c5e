"""`record`'s settings (`RecordConfig`), each field a flag (imitation.flags). Light, like the
learners' configs, for `record --help`."""

from __future__ import annotations

from dataclasses import dataclass

from imitation.errors import ConfigError
from imitation.flags import finite, flag, seed

COMPRESSIONS = ("lz4", "zstd", "none")  # imitation.data.mcap.format.COMPRESSIONS, without its mcap import
IMAGE_CODECS = ("png", "jpeg", "webp", "raw")


@dataclass(kw_only=True)
class RecordConfig:
    env_id: str = flag(name="--env", metavar="ID", help="gymnasium environment id, e.g. CartPole-v1")
    expert: str = flag(
        "scripted",
        metavar="SPEC",
        help="scripted (hand-written controller), random, keyboard (you play, discrete actions), a run directory with a "
        "policy, or sb3:ZIP (a stable-baselines3 policy, read without unpickling)",
    )
    episodes: int = flag(10, metavar="N", help="number of episodes")
    seed: int = flag(0, parse=seed, metavar="S", help="episode i is reset with seed S+i")
    compression: str = flag(
        "lz4",
        choices=COMPRESSIONS,
        help="chunk compression: lz4 (fast to load), zstd (about 10 %% smaller, for archives) or none",
    )
    frame_stack: int = flag(
        1, metavar="K", help="with --pixels: the number of frames learners stack by default; the file holds single frames"
    )
    image_codec: str = flag(
        "png",
        choices=IMAGE_CODECS,
        help="how frames are stored: png (lossless), jpeg (lossy, compact), webp (lossy, quality 85: about a third of "
        "jpeg's bytes at its 95; colour frames only) or raw (lossless, chunk-compressed)",
    )
    # DART: the env executes a random action with probability action_noise while the file stores
    # the expert's; with noise_bias that random action is mostly the episode's own (a steady push).
    action_noise: float = flag(
        0.0,
        parse=finite,
        metavar="P",
        help="with probability P the env executes a random action while the file stores the expert's (DART): demos of "
        "the states just off the expert's path, labelled",
    )
    noise_bias: float = flag(
        0.0,
        parse=finite,
        metavar="B",
        help="with --action-noise: a noisy step executes the episode's own random action (drawn at reset) with "
        "probability B, else a uniform one; noise with a mean, so the demos show the expert fighting a steady push "
        "(the drift a clone's own small bias causes)",
    )

    def validate(self, pixels: bool) -> None:
        """ConfigError for a setting out of range, or one that needs another (`pixels`: frames are recorded)."""
        if self.episodes < 1:
            raise ConfigError("episodes", f"must be at least 1, got {self.episodes}", owner="RecordConfig")
        if not 1 <= self.frame_stack <= 64:
            raise ConfigError("frame_stack", f"must be in [1, 64], got {self.frame_stack}", owner="RecordConfig")
        for name in ("action_noise", "noise_bias"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ConfigError(name, f"must be a probability in [0, 1], got {getattr(self, name)}", owner="RecordConfig")
        if self.noise_bias > 0 and self.action_noise == 0:
            raise ConfigError("noise_bias", "biases the action noise: give --action-noise too", owner="RecordConfig")
        if self.frame_stack > 1 and not pixels:
            raise ConfigError("frame_stack", "stacks rendered frames: give --pixels too", owner="RecordConfig")
