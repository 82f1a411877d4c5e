"""Benchmark: reading a demo file over HTTP by range requests, beside reading it from disk.

Serves one demo file from an HTTP server on 127.0.0.1 (tools/http_servers.py: a thread of this
process that honours `Range: bytes=a-b` and counts what it sends) and, for each load, reports the bytes served and
the requests made beside the file's size, and the median seconds over --repeats, next to the
same load from the local file (with the bytes the reader read there):

- open: `DemoFile(url)` (footer, summary, metadata records);
- info: what `imitation info` computes (`summarize`): for a URL the summary alone, for a local
  file also a check of every chunk;
- one episode: `demo[k]` on an open file, k in the middle;
- all episodes: `demo.read_episodes()`, and the bulk loader `load_transitions` (what training uses).

Data: the load benchmark's synthetic HalfCheetah file (bench/load.py; --episodes x --steps,
LZ4 chunks), taken from its cache under --data-dir when there, else written with DemoWriter.
Loopback HTTP measures the requests' overhead, not a network: the server shares this process's
CPU (and GIL) with the reader.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

BENCH = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCH.parent))
sys.path.insert(0, str(BENCH.parent / "tools"))

from http_servers import serve  # noqa: E402
from synth import OURS, make_rollouts, write_ours  # noqa: E402

from imitation.data.dataset import DemoDataset  # noqa: E402
from imitation.data.loader import load_transitions  # noqa: E402
from imitation.data.mcap.reader import DemoFile  # noqa: E402
from imitation.data.summary import summarize  # noqa: E402


def demo_file(args: argparse.Namespace) -> Path:
    """The load benchmark's cached file, or one written now with the same generator."""
    name = f"halfcheetah-e{args.episodes}-s{args.steps}-seed{args.seed}"
    cached = args.data_dir / name / f"{next(iter(OURS))}.mcap"
    if cached.exists():
        return cached
    path = args.data_dir / f"remote-{name}" / "ours.mcap"
    if not path.exists():
        print(f"writing {args.episodes} x {args.steps} transitions to {path} ...", flush=True)
        path.parent.mkdir(parents=True, exist_ok=True)
        write_ours(make_rollouts(args.episodes, args.steps, args.seed), path, OURS["ours"])
    return path


def bulk_load(path: Path) -> list[DemoFile]:
    """load_transitions of one file; the files it opened."""
    dataset = DemoDataset([path])
    load_transitions(dataset)
    return dataset.files


@dataclass
class Measured:
    """One load's median seconds and what one run of it read: bytes and requests (None: not counted)."""

    seconds: float
    bytes: int | None
    requests: int | None


def measure(load: Callable[[], Any], repeats: int, counter: Callable[[], tuple[int, int]] | None) -> Measured:
    """`load` run `repeats` times; `counter` (cumulative bytes, requests) is read around the last run."""
    seconds, read = [], None
    for _ in range(repeats):
        before = counter() if counter else (0, 0)
        started = time.perf_counter()
        load()
        seconds.append(time.perf_counter() - started)
        after = counter() if counter else (0, 0)
        read = (after[0] - before[0], after[1] - before[1])
    return Measured(statistics.median(seconds), read[0] if counter and read else None, read[1] if counter and read else None)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=1000, help="episodes in the data set (default 1000)")
    parser.add_argument("--steps", type=int, default=1000, help="steps per episode (default 1000)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the synthetic data (default 0)")
    parser.add_argument("--repeats", type=int, default=5, help="runs per load; the median is reported (default 5)")
    parser.add_argument("--data-dir", type=Path, default=BENCH / "data", help="where data sets live (default bench/data)")
    args = parser.parse_args()
    if min(args.episodes, args.steps, args.repeats) < 1:
        parser.error("--episodes, --steps and --repeats must be positive")

    path = demo_file(args)
    data = path.read_bytes()
    server = serve({"/demos.mcap": data})
    url = f"{server.url}/demos.mcap"
    remote, local = DemoFile(url), DemoFile(path)
    k = len(local) // 2
    opened: list[DemoFile] = []  # every file the local loads opened: their counters tell what they read

    def served() -> tuple[int, int]:
        return server.served.bytes, server.served.requests

    def read_locally() -> tuple[int, int]:
        return sum(demo.bytes_read for demo in opened), sum(demo.requests for demo in opened)

    def opening(load: Callable[[], list[DemoFile]]) -> Callable[[], None]:
        def run() -> None:
            opened.extend(load())

        return run

    rows = [
        ("open: DemoFile(path)", lambda: DemoFile(url), opening(lambda: [DemoFile(path)]), read_locally),
        ("info: summarize(path); locally it checks every chunk", lambda: summarize(url), lambda: summarize(path), None),
        (
            f"one episode: demo[{k}] of the open file",
            lambda: remote[k],
            lambda: local[k],
            lambda: (local.bytes_read, local.requests),
        ),
        (
            "all episodes: demo.read_episodes()",
            remote.read_episodes,
            local.read_episodes,
            lambda: (local.bytes_read, local.requests),
        ),
        (
            "all episodes, opening included: load_transitions (bulk)",
            lambda: load_transitions(url),
            opening(lambda: bulk_load(path)),
            read_locally,
        ),
    ]
    results = [
        (label, measure(over_http, args.repeats, served), measure(here, args.repeats, local_counter))
        for label, over_http, here, local_counter in rows
    ]
    server.stop()

    size = len(data)
    chunks = {c.offset: c for facts in local.episodes for c in local.chunks_of(facts)}
    episode_chunks = local.chunks_of(local.episodes[k])
    print(
        f"file: {path} ({size:,} bytes, {len(local)} episodes, {local.num_transitions:,} transitions, {len(chunks)} chunks); "
        f"episode {k}: {len(episode_chunks)} chunk(s), {sum(c.length for c in episode_chunks):,} bytes; "
        f"median of {args.repeats} runs\n"
    )
    print("| load | HTTP bytes served | % of file | HTTP requests | HTTP s | local s | local bytes read (reads) |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for label, over_http, here in results:
        assert over_http.bytes is not None
        local_read = "-" if here.bytes is None else f"{here.bytes:,} ({here.requests})"
        print(
            f"| {label} | {over_http.bytes:,} | {100 * over_http.bytes / size:.3f} | {over_http.requests} | "
            f"{over_http.seconds:.4f} | {here.seconds:.4f} | {local_read} |"
        )


if __name__ == "__main__":
    main()
