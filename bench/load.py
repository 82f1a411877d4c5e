"""Benchmark: load N transitions from disk into contiguous torch tensors, ours vs LeRobot vs raw.

Data: E synthetic HalfCheetah-like episodes of S steps (bench/synth.py), the same arrays written
to our MCAP demo file, a LeRobotDataset v3.0 and raw .npy files. Generated once and cached
under --data-dir; write times and sizes are recorded then.

Each load runs in a fresh Python process (bench/load_paths.py), timed from just before the
load call until the obs, action, reward and done tensors exist, imports excluded; runs are
interleaved across methods and the median of --repeats is reported.

Targets (issue 22): LeRobot's fastest bulk path / ours >= 3 (ours: the default, LZ4 chunks), and
ours / the floor of the same bytes <= 1.5 in wall and in CPU time, the floor being the same
chunks decompressed with the same codec on as many threads as ours uses.
Hugging Face libraries run with HF_HUB_OFFLINE=1 and HF_HOME under --data-dir.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from synth import OURS

BENCH = Path(__file__).resolve().parent
MIB = 1024 * 1024
BULK_TARGET = 3.0  # LeRobot bulk must take at least this many times our time
FLOOR_TARGET = 1.5  # ours may take at most this many times the floor of the same bytes (wall and CPU)


@dataclass(frozen=True)
class LoadPath:
    """One row of the table: a load_paths.py method, run with an optional fresh HF datasets cache."""

    key: str
    method: str
    label: str
    cold_hf_cache: bool = False
    lerobot_bulk: bool = False  # a candidate for "LeRobot's fastest bulk path"


PATHS = [
    LoadPath("ours", "ours", "ours (LZ4, the default): load_transitions + transitions_to_torch"),
    LoadPath("ours-zstd", "ours-zstd", "ours (zstd): load_transitions + transitions_to_torch"),
    LoadPath("ours-plain", "ours-plain", "ours (compression none): load_transitions + transitions_to_torch"),
    LoadPath("lerobot-arrow", "lerobot-arrow", "LeRobotDataset().hf_dataset.data (Arrow) columns, copied", lerobot_bulk=True),
    LoadPath("lerobot-hf-numpy", "lerobot-hf-numpy", 'LeRobotDataset().hf_dataset.with_format("numpy")[:]', lerobot_bulk=True),
    LoadPath("lerobot-hf-torch", "lerobot-hf-torch", 'LeRobotDataset().hf_dataset.with_format("torch")[:]', lerobot_bulk=True),
    LoadPath("lerobot-parquet", "lerobot-parquet", "pyarrow.parquet.read_table(<root>/data) columns", lerobot_bulk=True),
    LoadPath("lerobot-arrow-cold", "lerobot-arrow", "LeRobotDataset().hf_dataset.data, empty HF datasets cache (first open)", cold_hf_cache=True),
    LoadPath("lerobot-item", "lerobot-item", "LeRobotDataset()[i] for every i, torch.stack"),
    LoadPath("npy", "npy", "np.load of raw .npy arrays"),
    LoadPath("lz4-floor", "lz4-floor", "LZ4 floor: read ours.mcap's chunks + decompress, threaded as ours"),
    LoadPath("zstd-floor", "zstd-floor", "zstd floor: read ours-zstd.mcap's chunks + decompress, threaded as ours"),
]


@dataclass
class Runs:
    """Every measured run of one path."""

    path: LoadPath
    results: list[dict] = field(default_factory=list)

    @property
    def median(self) -> float:
        return statistics.median(r["seconds"] for r in self.results)

    @property
    def median_cpu(self) -> float:
        return statistics.median(r["cpu_seconds"] for r in self.results)


def hf_environment(data_root: Path) -> dict[str, str]:
    """The environment of every subprocess: Hugging Face libraries offline, their cache under data_root."""
    return {
        **os.environ,
        "HF_HUB_OFFLINE": "1",
        "HF_DATASETS_OFFLINE": "1",
        "HF_HOME": str(data_root / "hf_home"),
        # The checkout's own `imitation`, whether or not the venv has it installed.
        "PYTHONPATH": os.pathsep.join(filter(None, [str(BENCH.parent), os.environ.get("PYTHONPATH")])),
    }


def run_json(command: list[str], env: dict[str, str]) -> dict:
    """Run a bench script in a fresh process and parse the JSON on its last stdout line."""
    done = subprocess.run(command, env=env, capture_output=True, text=True)
    if done.returncode != 0:
        sys.stderr.write(done.stderr[-4000:])
        raise SystemExit(f"failed ({done.returncode}): {' '.join(command)}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def ensure_data(data: Path, args: argparse.Namespace, env: dict[str, str]) -> dict:
    """The cached data set's manifest, generating it first when missing (or asked to)."""
    manifest = data / "manifest.json"
    if args.regenerate and data.exists():
        shutil.rmtree(data)
    if manifest.exists() and json.loads(manifest.read_text()).get("compression") != OURS:
        print(f"bringing our files in {data} up to date (one per chunk compression) ...", flush=True)
        run_json([sys.executable, str(BENCH / "synth.py"), str(data), "--episodes", "0", "--steps", "0", "--ours-only"], env)
    if not manifest.exists():
        print(f"generating {args.episodes} x {args.steps} transitions into {data} (LeRobot's add_frame path takes a while) ...", flush=True)
        run_json([sys.executable, str(BENCH / "synth.py"), str(data), "--episodes", str(args.episodes), "--steps", str(args.steps), "--seed", str(args.seed)], env)
    return json.loads(manifest.read_text())


def warm_up(data: Path, env: dict[str, str]) -> None:
    """Put every file in the page cache and build LeRobot's HF datasets cache, so no timed run pays for either."""
    for file in sorted(p for p in data.rglob("*") if p.is_file()):
        with open(file, "rb") as stream:
            while stream.read(MIB):
                pass
    run_json([sys.executable, str(BENCH / "load_paths.py"), "lerobot-arrow", str(data)], env)


def measure(path: LoadPath, data: Path, env: dict[str, str], sample: int) -> dict:
    """One fresh-process run of `path`."""
    command = [sys.executable, str(BENCH / "load_paths.py"), path.method, str(data), "--sample", str(sample)]
    if not path.cold_hf_cache:
        return run_json(command, env)
    cache = Path(tempfile.mkdtemp(prefix="hf-datasets-cold-", dir=data.parent))
    try:
        result = run_json(command, {**env, "HF_DATASETS_CACHE": str(cache)})
        # What the first open added to disk: the Arrow copy datasets makes of the parquet files.
        result["hf_cache_bytes"] = sum(p.stat().st_size for p in cache.rglob("*") if p.is_file())
        return result
    finally:
        shutil.rmtree(cache)


def ratio_line(name: str, value: float, cpu_value: float, passed: bool, rule: str) -> str:
    """A target verdict; judged on wall time, the CPU-time ratio shown beside it for noisy machines."""
    return f"- {name}: **{value:.2f}** (target {rule}) → **{'PASS' if passed else 'FAIL'}**; by CPU time {cpu_value:.2f}"


def report(all_runs: list[Runs], manifest: dict, sample: int) -> str:
    """The Markdown tables and target verdicts."""
    total = manifest["transitions"]
    by_key = {runs.path.key: runs for runs in all_runs}
    ours = by_key["ours"].median
    bulk = min((runs for runs in all_runs if runs.path.lerobot_bulk), key=lambda runs: runs.median)
    lines = [
        f"Load {total:,} transitions ({manifest['episodes']:,} episodes x {manifest['steps']:,} steps) into contiguous torch tensors "
        f"(obs, action, reward, done); fresh process per run, median of {len(by_key['ours'].results)}.",
        "",
        "| path | median s | transitions/s | × ours | runs (s) | median CPU s | peak RSS MiB | checked |",
        "|---|---:|---:|---:|---|---:|---:|---|",
    ]
    for runs in all_runs:
        label = runs.path.label
        if runs.path is bulk.path:
            label += " ← fastest LeRobot bulk"
        if runs.results[0]["extrapolated"]:
            label += f" (**extrapolated** from {runs.results[0]['sampled']:,} items)"
        checked = {True: "= raw arrays", False: "**MISMATCH**", None: "n/a"}[
            None if runs.results[0]["matches_reference"] is None else all(r["matches_reference"] for r in runs.results)
        ]
        lines.append(
            f"| {label} | {runs.median:.3f} | {total / runs.median:,.0f} | {runs.median / ours:.2f} | "
            f"{', '.join(format(r['seconds'], '.3f') for r in runs.results)} | {runs.median_cpu:.3f} | {max(r['max_rss_mib'] for r in runs.results):,.0f} | {checked} |"
        )
    hf_cache_bytes = by_key["lerobot-arrow-cold"].results[0]["hf_cache_bytes"]
    writes, sizes = manifest["write_seconds"], manifest["bytes"]
    lines += ["", "Targets:", ""]
    for key in OURS:
        mine = by_key[key]
        bulk_ratio = bulk.median / mine.median
        lines.append(ratio_line(f"LeRobot bulk ({bulk.path.key}) / {key}", bulk_ratio, bulk.median_cpu / mine.median_cpu, bulk_ratio >= BULK_TARGET, f">= {BULK_TARGET:g}"))
    for key, floor_key in (("ours", "lz4-floor"), ("ours-zstd", "zstd-floor")):
        mine, floor = by_key[key], by_key[floor_key]
        wall, cpu = mine.median / floor.median, mine.median_cpu / floor.median_cpu
        lines.append(ratio_line(f"{key} / {floor_key}", wall, cpu, wall <= FLOOR_TARGET and cpu <= FLOOR_TARGET, f"<= {FLOOR_TARGET:g}, wall and CPU"))
    lines += [
        "",
        "Write (once, while generating; single run) and size on disk:",
        "",
        "| format | write s | transitions/s | size MiB |",
        "|---|---:|---:|---:|",
        *(
            f"| ours (write_episodes → MCAP, {OURS[key]}) | {writes[key]:.2f} | {total / writes[key]:,.0f} | {sizes[key] / MIB:.1f} |"
            for key in OURS
        ),
        f"| LeRobot (create, add_frame ×N, save_episode ×E, finalize) | {writes['lerobot']:.2f} | {total / writes['lerobot']:,.0f} | "
        f"{sizes['lerobot'] / MIB:.1f} (data parquet {sizes['lerobot_data_parquet'] / MIB:.1f}) |",
        f"| raw .npy (np.save) | {writes['npy']:.2f} | {total / writes['npy']:,.0f} | {sizes['npy'] / MIB:.1f} |",
        "",
        *(
            f"- LeRobot write time / ours ({OURS[key]}): **{writes['lerobot'] / writes[key]:.1f}×**; LeRobot size / ours: "
            f"**{sizes['lerobot'] / sizes[key]:.2f}×**"
            for key in ("ours", "ours-zstd")
        ),
        f"- LeRobotDataset's first open also writes an Arrow copy into the HF datasets cache: {hf_cache_bytes / MIB:.1f} MiB more on disk.",
        f"- Per-item path: {sample:,} `dataset[i]` calls timed, then scaled linearly to {total:,} (plus the measured open time).",
    ]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--episodes", type=int, default=1000, help="episodes in the data set (default 1000)")
    parser.add_argument("--steps", type=int, default=1000, help="steps per episode (default 1000)")
    parser.add_argument("--repeats", type=int, default=3, help="fresh-process runs per path; the median is reported (default 3)")
    parser.add_argument("--item-sample", type=int, default=20_000, help="dataset[i] calls timed for the per-item path (default 20000)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the synthetic data (default 0)")
    parser.add_argument("--data-dir", type=Path, default=BENCH / "data", help="where data sets and the HF cache live (default bench/data)")
    parser.add_argument("--regenerate", action="store_true", help="regenerate the data set even if it is cached")
    parser.add_argument("--json", type=Path, help="also write every run's raw result here")
    args = parser.parse_args()
    if min(args.episodes, args.steps, args.repeats, args.item_sample) < 1:
        parser.error("--episodes, --steps, --repeats and --item-sample must be positive")

    started = time.perf_counter()
    data_root = args.data_dir.resolve()
    data = data_root / f"halfcheetah-e{args.episodes}-s{args.steps}-seed{args.seed}"
    env = hf_environment(data_root)
    manifest = ensure_data(data, args, env)
    warm_up(data, env)

    all_runs = [Runs(path) for path in PATHS]
    # Interleaved, so drift in machine load spreads over every path instead of hitting one.
    for repeat in range(args.repeats):
        for runs in all_runs:
            print(f"run {repeat + 1}/{args.repeats}: {runs.path.key} ...", end=" ", flush=True)
            runs.results.append(measure(runs.path, data, env, args.item_sample))
            print(f"{runs.results[-1]['seconds']:.3f} s", flush=True)

    print()
    print(report(all_runs, manifest, args.item_sample))
    print(f"\nwhole benchmark: {time.perf_counter() - started:.0f} s wall (generation included when it ran)")
    if args.json:
        args.json.write_text(json.dumps({"manifest": manifest, "runs": {r.path.key: r.results for r in all_runs}}, indent=2))


if __name__ == "__main__":
    main()
