"""One load path, timed once, in this (fresh) process: run by bench/load.py, one process per run.

    python bench/load_paths.py METHOD DATA_DIR [--sample N]

Prints one JSON line: seconds (load call → contiguous torch tensors obs, action, reward, done),
transitions, whether the figure was extrapolated from a sample, peak RSS, and whether the
tensors equal the raw arrays in DATA_DIR/npy (checked after the clock stops).

Every path must end with tensors that hold the data in this process's own memory: a zero-copy
view of a memory-mapped file has not loaded anything yet, so such views are copied (and the copy
is timed).
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import resource
import sys
import time
from pathlib import Path
from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING, Callable

import numpy as np
import torch

from synth import LEROBOT_REPO_ID

if TYPE_CHECKING:  # imported lazily at run time, so that each path loads only its own libraries
    import pyarrow as pa
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

# (obs, action, reward, done) in this order everywhere.
Tensors = tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]
LEROBOT_COLUMNS = ["observation.state", "action", "next.reward", "next.done"]
NPY_NAMES = ["observations", "actions", "rewards", "dones"]



def _load_ours(file: Path) -> Tensors:
    """The public API a training script calls: load_transitions → transitions_to_torch.

    Without next_observations, like every other path here (obs, action, reward, done)."""
    from imitation.data.loader import load_transitions, transitions_to_torch

    batch = transitions_to_torch(load_transitions(file, next_observations=False), "cpu")
    return batch.observations, batch.actions, batch.rewards, batch.terminated | batch.truncated


def load_ours(data: Path) -> Tensors:
    """Our default file: LZ4-compressed chunks."""
    return _load_ours(data / "ours.mcap")


def load_ours_zstd(data: Path) -> Tensors:
    """The same episodes written with `compression="zstd"`."""
    return _load_ours(data / "ours-zstd.mcap")


def load_ours_plain(data: Path) -> Tensors:
    """The same episodes written with `compression="none"`: chunks are read in place (mmap)."""
    return _load_ours(data / "ours-plain.mcap")


def _open_lerobot(data: Path) -> LeRobotDataset:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    # No videos here; naming the backend keeps LeRobot from probing torchcodec, which needs FFmpeg.
    return LeRobotDataset(LEROBOT_REPO_ID, root=data / "lerobot", video_backend="pyav")


def load_lerobot_hf_torch(data: Path) -> Tensors:
    """LeRobotDataset → its HF dataset in torch format, all rows of the four columns at once."""
    columns = _open_lerobot(data).hf_dataset.with_format("torch", columns=LEROBOT_COLUMNS)[:]
    return tuple(columns[name] for name in LEROBOT_COLUMNS)  # type: ignore[return-value]


def load_lerobot_hf_numpy(data: Path) -> Tensors:
    """LeRobotDataset → its HF dataset in numpy format, all rows at once, then torch.from_numpy."""
    columns = _open_lerobot(data).hf_dataset.with_format("numpy", columns=LEROBOT_COLUMNS)[:]
    return tuple(torch.from_numpy(np.ascontiguousarray(columns[name])) for name in LEROBOT_COLUMNS)  # type: ignore[return-value]


def _arrow_column_to_tensor(column: pa.ChunkedArray) -> torch.Tensor:
    """A number column, or a fixed-size-list-of-numbers column, as one tensor that owns its memory.

    Each chunk (one per episode: LeRobot writes a row group per episode) becomes a zero-copy
    numpy view where Arrow allows it, and one concatenation copies them all into place: a single
    copy, which for the memory-mapped HF cache is the copy that actually loads the data.
    """
    import pyarrow as pa

    def chunk_values(chunk: pa.Array) -> np.ndarray:
        if isinstance(chunk, pa.FixedSizeListArray):
            return chunk.flatten().to_numpy(zero_copy_only=False).reshape(len(chunk), chunk.type.list_size)
        return chunk.to_numpy(zero_copy_only=False)

    return torch.from_numpy(np.concatenate([chunk_values(chunk) for chunk in column.chunks]))


def load_lerobot_arrow(data: Path) -> Tensors:
    """LeRobotDataset → `hf_dataset.data`, the Arrow table behind it (memory-mapped HF cache), column by column."""
    table = _open_lerobot(data).hf_dataset.data
    return tuple(_arrow_column_to_tensor(table.column(name)) for name in LEROBOT_COLUMNS)  # type: ignore[return-value]


def load_lerobot_parquet(data: Path) -> Tensors:
    """No LeRobotDataset object: pyarrow reads the four columns of its data/*/*.parquet files."""
    import pyarrow.parquet as pq

    table = pq.read_table(data / "lerobot" / "data", columns=LEROBOT_COLUMNS)
    return tuple(_arrow_column_to_tensor(table.column(name)) for name in LEROBOT_COLUMNS)  # type: ignore[return-value]


def load_npy(data: Path) -> Tensors:
    """np.load of one .npy file per array (read into memory, not memory-mapped)."""
    return tuple(torch.from_numpy(np.load(data / "npy" / f"{name}.npy")) for name in NPY_NAMES)  # type: ignore[return-value]


def _chunk_payloads(file: Path) -> list[tuple[int, int, int]]:
    """(offset, length, uncompressed size) of every chunk's compressed payload, from the summary's
    chunk index, as ours finds them. A Chunk record is opcode and length (9 bytes), start and end
    time, uncompressed size (8 each), CRC (4), the compression name (4 + n) and the payload's length (8)."""
    from mcap.reader import make_reader

    with open(file, "rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    return [
        (
            index.chunk_start_offset + 9 + 28 + 4 + len(index.compression) + 8,
            index.compressed_size,
            index.uncompressed_size,
        )
        for index in summary.chunk_indexes
    ]


def floor(data: Path, codec: str) -> int:
    """Read every chunk payload of our file with that codec and decompress it; nothing else.
    As ours does: each chunk read by pread and decompressed on a pool of min(chunks, cores, 8)
    threads (both codecs release the GIL). Returns the bytes decompressed."""
    import lz4.frame
    import zstandard

    file = data / ("ours.mcap" if codec == "lz4" else "ours-zstd.mcap")
    chunks = _chunk_payloads(file)

    def decompress(fd: int, chunk: tuple[int, int, int]) -> int:
        offset, length, size = chunk
        payload = os.pread(fd, length, offset)
        if codec == "lz4":
            return len(lz4.frame.decompress(payload))
        return len(zstandard.ZstdDecompressor().decompress(payload, max_output_size=size))

    with open(file, "rb") as stream, ThreadPoolExecutor(max_workers=min(len(chunks), os.cpu_count() or 1, 8) or 1) as pool:
        return sum(pool.map(lambda chunk: decompress(stream.fileno(), chunk), chunks))


FULL_PATHS: dict[str, Callable[[Path], Tensors]] = {
    "ours": load_ours,
    "ours-zstd": load_ours_zstd,
    "ours-plain": load_ours_plain,
    "lerobot-hf-torch": load_lerobot_hf_torch,
    "lerobot-hf-numpy": load_lerobot_hf_numpy,
    "lerobot-arrow": load_lerobot_arrow,
    "lerobot-parquet": load_lerobot_parquet,
    "npy": load_npy,
}


_LEROBOT_IMPORTS = ("lerobot.datasets.lerobot_dataset", "pyarrow.parquet")
IMPORTS: dict[str, tuple[str, ...]] = {
    "ours": ("imitation.data.loader",),
    "ours-zstd": ("imitation.data.loader",),
    "ours-plain": ("imitation.data.loader",),
    "lz4-floor": ("lz4.frame", "zstandard", "mcap.reader"),
    "zstd-floor": ("lz4.frame", "zstandard", "mcap.reader"),
    **{name: _LEROBOT_IMPORTS for name in FULL_PATHS if name.startswith("lerobot")},
    "lerobot-item": _LEROBOT_IMPORTS,
}


def clock() -> tuple[float, float]:
    """(wall, CPU) seconds now; CPU time counts every thread of this process and, unlike wall
    time, hardly moves when other work competes for the cores."""
    return time.perf_counter(), time.process_time()


def lerobot_items(data: Path, sample: int) -> tuple[Tensors, tuple[float, float], tuple[float, float]]:
    """`dataset[i]` for i < sample, stacked. Returns (tensors, (wall, CPU) to open, (wall, CPU) for the items and stack)."""
    start = clock()
    dataset = _open_lerobot(data)
    opened = clock()
    items = [dataset[i] for i in range(min(sample, len(dataset)))]
    tensors = tuple(torch.stack([item[name] for item in items]) for name in LEROBOT_COLUMNS)
    end = clock()
    return tensors, (opened[0] - start[0], opened[1] - start[1]), (end[0] - opened[0], end[1] - opened[1])  # type: ignore[return-value]


def matches_reference(data: Path, tensors: Tensors) -> bool:
    """Whether the tensors equal the first rows of the raw arrays, exactly, and are contiguous."""
    for tensor, name in zip(tensors, NPY_NAMES):
        reference = torch.from_numpy(np.load(data / "npy" / f"{name}.npy", mmap_mode="r")[: len(tensor)].copy())
        if not tensor.is_contiguous() or tensor.shape != reference.shape or not torch.equal(tensor, reference):
            return False
    return True


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("method", choices=[*FULL_PATHS, "lerobot-item", "lz4-floor", "zstd-floor"])
    parser.add_argument("data", type=Path)
    parser.add_argument("--sample", type=int, default=20_000, help="items read by lerobot-item")
    args = parser.parse_args()
    manifest = json.loads((args.data / "manifest.json").read_text())
    total = int(manifest["transitions"])
    # Imported before the clock starts (the benchmark excludes imports), and only what this path
    # uses, so peak RSS is not inflated by other libraries.
    for module in IMPORTS.get(args.method, ()):
        importlib.import_module(module)

    result: dict = {"method": args.method, "transitions": total, "extrapolated": False}
    tensors: Tensors | None = None
    if args.method == "lerobot-item":
        tensors, opening, items = lerobot_items(args.data, args.sample)
        count = len(tensors[0])
        # Linear in the item count: each item is an independent lookup into the same Arrow table.
        result.update(
            seconds=opening[0] + items[0] * total / count,
            cpu_seconds=opening[1] + items[1] * total / count,
            extrapolated=count < total,
            sampled=count,
            open_seconds=opening[0],
            measured_seconds=opening[0] + items[0],
        )
    else:
        start = clock()
        if args.method.endswith("-floor"):
            result["decompressed_bytes"] = floor(args.data, args.method.removesuffix("-floor"))
        else:
            tensors = FULL_PATHS[args.method](args.data)
        end = clock()
        result.update(seconds=end[0] - start[0], cpu_seconds=end[1] - start[1])
        if tensors is not None and len(tensors[0]) != total:
            sys.exit(f"{args.method}: loaded {len(tensors[0])} transitions, expected {total}")
    # Before the check below, which loads the reference arrays. ru_maxrss is in KiB on Linux.
    result["max_rss_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    result["matches_reference"] = None if tensors is None else matches_reference(args.data, tensors)
    json.dump(result, sys.stdout)
    print()


if __name__ == "__main__":
    main()
