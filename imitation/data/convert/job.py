"""`imitation convert`: recognise the source, run its converter, fit an env, settle the end flags,
write the demo file."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from imitation.data.convert.bags import MCAP_MAGIC, ROS1_MAGIC
from imitation.data.convert.converted import fit_to_env, write_converted
from imitation.data.convert.endings import recording_end_flags, settle_ends
from imitation.data.mcap.source import refuse_url
from imitation.errors import ImitationError
from imitation.inputs import check_input, open_input

SOURCES = ("ros2", "ros1", "lerobot", "npz", "array")
# HDF5's signature, at the start of the file or after a user block of 512 bytes times a power of two.
HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"
HDF5_OFFSETS = (0, 512, 1024, 2048)


def detect_source(path: str | Path) -> str:
    """ros2, ros1, lerobot, npz or array, from the path's layout and first bytes; HDF5 files are
    refused with a way to convert their arrays."""
    path = Path(path)
    if not path.exists():
        raise ImitationError(f"{path}: no such file or directory")
    check_input(path)
    if path.is_dir():
        if (path / "meta" / "info.json").is_file():
            return "lerobot"
        if (path / "metadata.yaml").is_file() or any(path.glob("*.mcap")) or any(path.glob("*.db3")):
            return "ros2"
        if (path / "meta").is_dir() or (path / "data").is_dir():
            raise ImitationError(f"{path}: looks like a LeRobot dataset root but has no meta/info.json")
        raise ImitationError(
            f"{path}: cannot tell what this folder holds (a rosbag2 directory or a LeRobot dataset root); say it with --from"
        )
    try:
        with open_input(path) as stream:
            head = stream.read(HDF5_OFFSETS[-1] + len(HDF5_MAGIC))
    except OSError as error:
        raise ImitationError(f"{path}: cannot read: {error.strerror or error}") from None
    if head.startswith(MCAP_MAGIC) or path.suffix == ".db3":
        return "ros2"
    if head.startswith(ROS1_MAGIC):
        return "ros1"
    if head.startswith(b"PK") and path.suffix == ".npz":
        return "npz"
    if head.startswith(b"\x93NUMPY"):
        return "array"
    if any(head[offset : offset + len(HDF5_MAGIC)] == HDF5_MAGIC for offset in HDF5_OFFSETS):
        raise ImitationError(
            f"{path}: an HDF5 file, which convert does not read (no --from does); save its episodes with h5py as one "
            "(episodes, steps, columns) array in an .npy file and convert that with --layout (docs/CONVERT.md, Bare arrays)"
        )
    raise ImitationError(f"{path}: cannot tell its format (not MCAP, a ROS 1 bag or an npz archive); say it with --from")


def _source_kind(path: str | Path, source: str | None) -> str:
    if source is None:
        return detect_source(path)
    if source not in SOURCES:
        raise ImitationError(f"--from {source}: unknown source; use one of {', '.join(SOURCES)}")
    if not Path(path).exists():
        raise ImitationError(f"{path}: no such file or directory")
    check_input(path)
    return source


def convert(
    path: str | Path,
    out: str | Path,
    *,
    source: str | None = None,
    map_path: str | Path | None = None,
    layout_path: str | Path | None = None,
    env_id: str | None = None,
    ros_distro: str = "latest",
    progress: bool = True,
    image_codec: str = "png",
    image_quality: int | None = None,
    image_size: tuple[int, int] | None = None,
    video_tolerance_s: float | None = None,
) -> dict[str, Any]:
    """Convert `path` into demo file `out`; returns what `imitation convert --json` prints.
    `image_codec` and `image_quality` say how camera frames are stored (write_converted),
    `image_size` (height, width) resizes them (a bag's map entry may say its own `resize`),
    `video_tolerance_s` places a LeRobot dataset's video frames by timestamp (lerobot.py)."""
    refuse_url(out)
    kind = _source_kind(path, source)
    if image_size is not None and kind in ("npz", "array"):
        raise ImitationError(f"--image-size resizes the cameras of bags and LeRobot datasets; {path} is a {kind} source")
    if video_tolerance_s is not None and kind != "lerobot":
        raise ImitationError(f"--video-tolerance places a LeRobot dataset's video frames; {path} is a {kind} source")
    if kind == "npz" and layout_path is not None and source is None:
        kind = "array"  # an npz member described by a layout
    if kind == "array" and layout_path is None:
        raise ImitationError(
            f"{path}: a bare array needs --layout LAYOUT.yaml saying what its rows and columns hold (docs/CONVERT.md)"
        )
    if kind != "array" and layout_path is not None:
        raise ImitationError(f"--layout is for bare arrays (.npy, or an npz member); {path} is a {kind} source")
    if kind in ("ros2", "ros1"):
        if map_path is None:
            raise ImitationError(
                f"{path}: converting a bag needs --map MAP.yaml (`imitation convert {path} --inspect --write-map map.yaml` "
                "writes a starter)"
            )
        from imitation.data.convert.bags import open_bag
        from imitation.data.convert.maps import load_map
        from imitation.data.convert.ros import bag_to_episodes

        recording_map = load_map(map_path)
        env_id = env_id or recording_map.env_id
        bag = open_bag(path, kind, ros_distro=ros_distro)
        try:
            converted = recording_end_flags(bag_to_episodes(bag, recording_map, progress=progress, image_size=image_size))
        finally:
            bag.close()
    else:
        if map_path is not None:
            raise ImitationError(f"--map is for ROS bags; {path} is a {kind} source")
        if kind == "lerobot":
            from imitation.data.convert.lerobot import lerobot_to_episodes

            converted = lerobot_to_episodes(
                path, progress=progress, video_tolerance_s=video_tolerance_s, image_size=image_size
            )
        elif kind == "array":
            from imitation.data.convert.arrays import array_to_episodes, load_layout

            assert layout_path is not None
            converted = array_to_episodes(path, load_layout(layout_path))
        else:
            from imitation.data.convert.npz import npz_to_episodes

            converted = npz_to_episodes(path)
    # An env named by --env or the map supplies the spaces; a LeRobot sidecar's are exact already.
    if env_id:
        converted = fit_to_env(converted, env_id)
    if converted.end_at_terminal_state is not None:
        from imitation.data.convert.terminal_states import end_at_terminal_states

        converted = end_at_terminal_states(converted, converted.end_at_terminal_state)
    # Sources that cannot tell a time limit from a termination: decide from the env's limit, or say so.
    converted = settle_ends(converted)
    return {
        "from": kind,
        **write_converted(converted, out, progress=progress, image_codec=image_codec, image_quality=image_quality),
    }


def inspect(
    path: str | Path, *, source: str | None = None, write_map: str | Path | None = None, ros_distro: str = "latest"
) -> dict[str, Any]:
    """Describe a bag's topics and fields; optionally write a starter map."""
    from imitation.data.convert.bags import open_bag
    from imitation.data.convert.inspect import inspect_bag, write_starter_map

    kind = _source_kind(path, source)
    if kind not in ("ros2", "ros1"):
        raise ImitationError(f"--inspect is for ROS bags; {path} is a {kind} source (convert it directly)")
    bag = open_bag(path, kind, ros_distro=ros_distro)
    try:
        report = inspect_bag(bag)
    finally:
        bag.close()
    report["from"] = kind
    report["map"] = str(write_starter_map(report, write_map)) if write_map else None
    return report
