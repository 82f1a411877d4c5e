"""Resource bounds checked before anything is allocated, so that a small hostile file (a space
declaring 2^26 numbers, a chunk of zeros expanding a thousandfold, a YAML alias bomb, camera
frames that decode to gigabytes, a JPEG of thousands of scans) is refused in one line instead of
exhausting memory or CPU.

Every bound is generous for real data and can be raised for one run with the global option
`imitation --limit NAME=VALUE` (repeatable), or the environment variable
`IMITATION_LIMITS="NAME=VALUE,..."`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import zipfile
from dataclasses import dataclass

from imitation.errors import ImitationError


@dataclass
class Limits:
    # Numbers in one sample of a space (all leaves of a Dict together): 2^23 holds a 1080p RGB
    # frame with room to spare, and its float64 bounds stay under 150 MB.
    sample_elements: int = 2**23
    # Leaves of a Dict space.
    dict_leaves: int = 1024
    # Decompressed bytes of a file's chunks per byte of the file (beyond the first 64 MiB).
    expansion_ratio: int = 100
    # Bytes one chunk may decompress to.
    chunk_bytes: int = 2**28
    # Nodes of a YAML document (maps, bag metadata) after aliases are expanded.
    yaml_nodes: int = 100_000
    # Weights of a policy network (2^27 float32 weights are 512 MiB).
    policy_parameters: int = 2**27
    # Steps of a bag's resampled episode per message of its mapped topics inside it (ros.py). The
    # grid steps at the map's rate_hz, so a real bag stays far below: its topics publish at rates
    # like the grid's (a ratio near 1), and even a 100 Hz grid over topics that together publish
    # once per 10 s is only 1000, however long the bag. A grid thousands of times denser than the
    # data is a damaged stamp stretching a few messages over days (a 7.8 KB bag would be 44 million
    # steps, 3.9 GB); a real silence that long belongs between episodes (`episodes: {split: gap}`).
    grid_steps_per_message: int = 1000
    # Bytes of decoded camera frames per byte of the file or folder that holds them (beyond the
    # first 64 MiB): PNG and JPEG frames of a demo file, a ROS bag's camera messages on the
    # resampled grid, a LeRobot dataset's images and video frames. Measured on real data, the
    # most compressible are CartPole rendered at 400x600 (PNG 373, JPEG 467) and LeRobot's AV1
    # and H.264 videos (SO-101 344, ALOHA sim 326 to 359); SO-101's wrist camera as PNG frames
    # is 18, as JPEG (quality 95) 65. A 34 KB file of identical frames decoding to 3 GB is 90,000.
    image_expansion_ratio: int = 2000
    # Scans of one JPEG frame. A progressive JPEG's scans each pass over the whole picture, and a
    # scan of "nothing changed" takes 12 bytes: 600 of them made an 8 KB 1080p frame take 0.6 s
    # to decode. Encoders write 1 (baseline) or 3 (one per colour), libjpeg's progressive mode
    # 10 (colour) or 6 (grey), mozjpeg's searched progressions about a dozen.
    jpeg_scans: int = 100
    # Demo files read from URLs (data/mcap/remote_reads.py): what a server may cost. Seconds it
    # may send nothing, to connect, to answer or between bytes: object stores answer within a
    # second, and a transfer stalled this long over the internet seldom resumes.
    remote_stall_seconds: int = 30
    # Seconds one request may take, asked to last byte. Reading asks for a chunk at a time (about
    # 1 MiB as the writer makes them: 4 KB/s suffices); a salvage scan asks for the whole object
    # at once (remote_request_bytes at 1 MB/s take 268 s).
    remote_request_seconds: int = 300
    # Seconds of one command spent waiting on remote reads, all requests together (wall time with
    # any in flight): 100 GB of demos at 10 MB/s take 2.8 h.
    remote_total_seconds: int = 4 * 3600
    # Bytes one request may bring. A chunk is about 1 MiB; a salvage scan of a damaged remote file
    # holds all of it in memory (a larger one is salvaged from a downloaded copy); a server that
    # ignores Range sends everything before the range as well.
    remote_request_bytes: int = 2**28


LIMITS = Limits()
FREE_EXPANSION_BYTES = 64 * 2**20


def set_limit(assignment: str) -> None:
    """Apply one `NAME=VALUE` (VALUE a positive integer)."""
    name, _, value = assignment.partition("=")
    names = [f.name for f in dataclasses.fields(Limits)]
    if name not in names:
        raise ImitationError(f"--limit {assignment[:100]}: unknown limit; the limits are {', '.join(names)}")
    if not (value.isdigit() and len(value) <= 19 and int(value) >= 1):
        raise ImitationError(f"--limit {assignment[:100]}: the value must be a positive integer such as 16777216")
    number = int(value)
    setattr(LIMITS, name, number)


def limits_from_environment() -> None:
    for assignment in filter(None, os.environ.get("IMITATION_LIMITS", "").split(",")):
        set_limit(assignment.strip())


def over_limit(what: str, amount: int, name: str) -> ImitationError:
    """The one-line error for `amount` above limit `name`, saying how to raise it."""
    return ImitationError(
        f"{what}: {amount} is more than the limit {name}={getattr(LIMITS, name)} (raise it with `imitation --limit {name}=N` "
        "if the data is real)"
    )


def input_bytes(path: str | os.PathLike) -> int:
    """Bytes of a file, or of every file in a folder and its subfolders (symlinked folders not
    followed): what decoded frames are counted against."""
    if not os.path.isdir(path):
        return os.path.getsize(path)
    total = 0
    for folder, _, names in os.walk(os.fspath(path)):
        for name in names:
            with contextlib.suppress(OSError):  # a dangling link holds nothing
                total += os.path.getsize(os.path.join(folder, name))
    return total


class ImageBudget:
    """Decoded bytes of camera frames from one input, counted before each frame (or batch of
    frames) is decoded, against `image_expansion_ratio` times the input's size: frames that
    compress ten-thousandfold are refused in one line instead of filling memory."""

    def __init__(self, what: str, source_bytes: int) -> None:
        """`what` names the input in the error."""
        self.what, self.source_bytes, self.decoded = what, source_bytes, 0
        self.allowed = max(FREE_EXPANSION_BYTES, LIMITS.image_expansion_ratio * source_bytes)

    def take(self, amount: int) -> None:
        """Count `amount` more decoded bytes; ImitationError once the total passes the bound."""
        self.decoded += amount
        if self.decoded > self.allowed:
            raise ImitationError(
                f"{self.what}: decoded bytes of its camera frames (from {self.source_bytes} bytes): {self.decoded} is more "
                f"than the limit image_expansion_ratio={LIMITS.image_expansion_ratio} (raise it with "
                "`imitation --limit image_expansion_ratio=N` if the data is real)"
            )


def check_zip_member(file: str | os.PathLike, info: zipfile.ZipInfo) -> None:
    """Refuse a zip member whose declared size the archive cannot hold, before reading it: a
    small crafted zip (an SB3 model, an npz) must not make the reader allocate gigabytes."""
    allowed = max(FREE_EXPANSION_BYTES, LIMITS.expansion_ratio * max(info.compress_size, 1))
    if info.compress_size > os.path.getsize(file):
        raise ImitationError(
            f"{file}: zip member {info.filename[:100]!r} is damaged (it claims more bytes than the archive has)"
        )
    if info.file_size > allowed:
        raise over_limit(f"{file}: zip member {info.filename[:100]!r}: declared bytes", info.file_size, "expansion_ratio")
