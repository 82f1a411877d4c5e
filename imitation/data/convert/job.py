"""`imitation convert`: recognise the source, run its converter, fit an env, settle the end flags,
write the demo file."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from imitation.data.convert.converted import fit_to_env, write_converted
from imitation.data.convert.endings import settle_ends
from imitation.data.convert.sources import SOURCES, Request, Source, source_named
from imitation.data.mcap.source import refuse_url
from imitation.errors import ImitationError
from imitation.inputs import check_input, open_input

# HDF5's signature, at the start of the file or after a user block of 512 bytes times a power of two.
HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"
HDF5_OFFSETS = (0, 512, 1024, 2048)


def detect_source(path: str | Path) -> str:
    """The registered source (imitation.data.convert.sources) that recognises the path's layout or
    first bytes; HDF5 files are refused with a way to convert their arrays."""
    path = Path(path)
    if not path.exists():
        raise ImitationError(f"{path}: no such file or directory")
    check_input(path)
    head = b""
    if not path.is_dir():
        try:
            with open_input(path) as stream:
                head = stream.read(HDF5_OFFSETS[-1] + len(HDF5_MAGIC))
        except OSError as error:
            raise ImitationError(f"{path}: cannot read: {error.strerror or error}") from None
    for source in SOURCES.values():
        if source.recognise(path, head):
            return source.name
    if path.is_dir():
        if (path / "meta").is_dir() or (path / "data").is_dir():
            raise ImitationError(f"{path}: looks like a LeRobot dataset root but has no meta/info.json")
        raise ImitationError(
            f"{path}: cannot tell what this folder holds (a rosbag2 directory or a LeRobot dataset root); say it with --from"
        )
    if any(head[offset : offset + len(HDF5_MAGIC)] == HDF5_MAGIC for offset in HDF5_OFFSETS):
        raise ImitationError(
            f"{path}: an HDF5 file, which convert does not read (no --from does); save its episodes with h5py as one "
            "(episodes, steps, columns) array in an .npy file and convert that with --layout (docs/CONVERT.md, Bare arrays)"
        )
    raise ImitationError(f"{path}: cannot tell its format (not MCAP, a ROS 1 bag or an npz archive); say it with --from")


def _source(path: str | Path, named: str | None) -> Source:
    if named is None:
        return SOURCES[detect_source(path)]
    source = source_named(named)
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
    chosen = _source(path, source)
    request = Request(
        Path(path),
        map_path=map_path,
        layout_path=layout_path,
        env_id=env_id,
        ros_distro=ros_distro,
        progress=progress,
        image_size=image_size,
        video_tolerance_s=video_tolerance_s,
    )
    _refuse_options(chosen, request, ("image_size", "video_tolerance_s"))
    if chosen.with_layout is not None and layout_path is not None and source is None:
        chosen = SOURCES[chosen.with_layout]  # a member of the file described by a layout
    if chosen.require is not None:
        chosen.require(request)
    _refuse_options(chosen, request, ("layout_path", "map_path"))
    converted, env_id = chosen.convert(request)
    # An env named by --env or the map supplies the spaces; a LeRobot sidecar's are exact already.
    if env_id:
        converted = fit_to_env(converted, env_id)
    if converted.end_at_terminal_state is not None:
        from imitation.data.convert.terminal_states import end_at_terminal_states

        converted = end_at_terminal_states(converted, converted.end_at_terminal_state)
    # Sources that cannot tell a time limit from a termination: decide from the env's limit, or say so.
    converted = settle_ends(converted)
    return {
        "from": chosen.name,
        **write_converted(converted, out, progress=progress, image_codec=image_codec, image_quality=image_quality),
    }


def inspect(
    path: str | Path, *, source: str | None = None, write_map: str | Path | None = None, ros_distro: str = "latest"
) -> dict[str, Any]:
    """Describe a bag's topics and fields; optionally write a starter map."""
    from imitation.data.convert.bags import open_bag
    from imitation.data.convert.inspect import inspect_bag, write_starter_map

    kind = _source(path, source).name
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


def _refuse_options(source: Source, request: Request, options: tuple[str, ...]) -> None:
    """A one-line error for the first of `options` given to a source that does not take it."""
    for option in options:
        if getattr(request, option) is None or option in source.takes:
            continue
        path, kind = request.path, source.name
        if option == "image_size":
            raise ImitationError(
                "--image-size resizes the cameras of bags, LeRobot datasets and zarr replay buffers; "
                f"{path} is a {kind} source"
            )
        if option == "video_tolerance_s":
            raise ImitationError(f"--video-tolerance places a LeRobot dataset's video frames; {path} is a {kind} source")
        if option == "layout_path":
            raise ImitationError(f"--layout is for bare arrays (.npy, or an npz member); {path} is a {kind} source")
        raise ImitationError(f"--map is for ROS bags; {path} is a {kind} source")
