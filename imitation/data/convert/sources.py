"""The recordings `convert` reads, one entry each: how a path is recognised (its layout or first
bytes), which of convert's options it takes, and its converter. A new source is a converter
module and one `register(Source(...))`; job.py runs whichever `detect_source` or `--from` names.

Light on purpose (the converters are imported when they run): `convert --help` lists the names.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from imitation.errors import ImitationError

if TYPE_CHECKING:
    from imitation.data.convert.converted import Converted

MCAP_MAGIC = b"\x89MCAP0\r\n"
ROS1_MAGIC = b"#ROSBAG V2.0"
# convert's options that only some sources take (the `Request` fields a Source's `takes` names).
SOURCE_OPTIONS = ("map_path", "layout_path", "image_size", "video_tolerance_s")


@dataclass(frozen=True)
class Request:
    """What `convert` was asked: the source's path and the options that concern its converter."""

    path: Path
    map_path: str | Path | None = None
    layout_path: str | Path | None = None
    env_id: str | None = None
    ros_distro: str = "latest"
    progress: bool = True
    image_size: tuple[int, int] | None = None
    video_tolerance_s: float | None = None


@dataclass(frozen=True)
class Source:
    """One kind of recording. `convert` returns its episodes and the env they are fitted to (None:
    none; `--env`, or what the recording names). `recognise` sees the path and its first bytes
    (b"" for a folder); `takes` names the `SOURCE_OPTIONS` it accepts, and `require` refuses what it
    cannot do without (a bag without its map). `with_layout` is the source a file of this kind
    is read as when a layout describes one of its members."""

    name: str
    convert: Callable[[Request], tuple[Converted, str | None]]
    recognise: Callable[[Path, bytes], bool]
    takes: frozenset[str] = frozenset()
    require: Callable[[Request], None] | None = None
    with_layout: str | None = None

    def __post_init__(self) -> None:
        if unknown := self.takes - set(SOURCE_OPTIONS):
            raise ValueError(f"source {self.name}: takes {sorted(unknown)}, not among {SOURCE_OPTIONS}")


SOURCES: dict[str, Source] = {}


def register(source: Source) -> None:
    """Add a source `convert` recognises and `--from` names (a later one of the same name replaces it)."""
    SOURCES[source.name] = source


def source_named(name: str) -> Source:
    if name not in SOURCES:
        raise ImitationError(f"--from {name}: unknown source; use one of {', '.join(SOURCES)}")
    return SOURCES[name]


def _ros_bag(request: Request, kind: str) -> tuple[Converted, str | None]:
    from imitation.data.convert.bags import open_bag
    from imitation.data.convert.endings import recording_end_flags
    from imitation.data.convert.maps import load_map
    from imitation.data.convert.ros import bag_to_episodes

    assert request.map_path is not None
    recording_map = load_map(request.map_path)
    bag = open_bag(request.path, kind, ros_distro=request.ros_distro)
    try:
        episodes = bag_to_episodes(bag, recording_map, progress=request.progress, image_size=request.image_size)
        converted = recording_end_flags(episodes)
    finally:
        bag.close()
    return converted, request.env_id or recording_map.env_id


def _needs_map(request: Request) -> None:
    if request.map_path is None:
        raise ImitationError(
            f"{request.path}: converting a bag needs --map MAP.yaml (`imitation convert {request.path} --inspect "
            "--write-map map.yaml` writes a starter)"
        )


def _lerobot(request: Request) -> tuple[Converted, str | None]:
    from imitation.data.convert.lerobot import lerobot_to_episodes

    converted = lerobot_to_episodes(
        request.path, progress=request.progress, video_tolerance_s=request.video_tolerance_s, image_size=request.image_size
    )
    return converted, request.env_id


def _npz(request: Request) -> tuple[Converted, str | None]:
    from imitation.data.convert.npz import npz_to_episodes

    return npz_to_episodes(request.path), request.env_id


def _array(request: Request) -> tuple[Converted, str | None]:
    from imitation.data.convert.arrays import array_to_episodes, load_layout

    assert request.layout_path is not None
    return array_to_episodes(request.path, load_layout(request.layout_path)), request.env_id


def _needs_layout(request: Request) -> None:
    if request.layout_path is None:
        raise ImitationError(
            f"{request.path}: a bare array needs --layout LAYOUT.yaml saying what its rows and columns hold (docs/CONVERT.md)"
        )


def _rosbag2_folder(path: Path) -> bool:
    return (path / "metadata.yaml").is_file() or any(path.glob("*.mcap")) or any(path.glob("*.db3"))


BAG_OPTIONS = frozenset({"map_path", "image_size"})
register(
    Source(
        "ros2",
        lambda request: _ros_bag(request, "ros2"),
        lambda path, head: _rosbag2_folder(path) if path.is_dir() else head.startswith(MCAP_MAGIC) or path.suffix == ".db3",
        BAG_OPTIONS,
        _needs_map,
    )
)
register(
    Source(
        "ros1", lambda request: _ros_bag(request, "ros1"), lambda _, head: head.startswith(ROS1_MAGIC), BAG_OPTIONS, _needs_map
    )
)
register(
    Source(
        "lerobot",
        _lerobot,
        lambda path, _: path.is_dir() and (path / "meta" / "info.json").is_file(),
        frozenset({"image_size", "video_tolerance_s"}),
    )
)


def _zarr(request: Request) -> tuple[Converted, str | None]:
    from imitation.data.convert.zarr_replay import replay_to_episodes

    converted = replay_to_episodes(
        request.path, env_id=request.env_id, progress=request.progress, image_size=request.image_size
    )
    return converted, request.env_id


def _zarr_group(path: Path, _: bytes) -> bool:
    from imitation.data.convert.zarr_replay import is_replay_buffer

    return is_replay_buffer(path)


register(Source("npz", _npz, lambda path, head: head.startswith(b"PK") and path.suffix == ".npz", with_layout="array"))
register(Source("array", _array, lambda _, head: head.startswith(b"\x93NUMPY"), frozenset({"layout_path"}), _needs_layout))
register(Source("zarr", _zarr, _zarr_group, frozenset({"image_size"})))
