"""Does this machine charge for memory a process touches for the first time?

A VM with free-page reporting hands freed guest memory back to its host, and touching it again is
a host fault. This fills a fresh numpy array of --gib GiB three times in one process (the first
fill takes memory from the kernel, the next ones reuse what the process freed) and prints each
time: a first fill far slower than the others is what `bench/pixels_load.py --prefault-gib` is for.

Usage: python bench/vm_memory.py [--gib 1.2]
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--gib", type=float, default=1.2, help="size of each fill (default 1.2, our frames' size)")
    args = parser.parse_args()
    size = int(args.gib * 2**30)
    for fill in range(1, 4):
        array = np.empty(size, dtype=np.uint8)
        started = time.perf_counter()
        array[:] = 1
        seconds = time.perf_counter() - started
        print(f"fill {fill}: {args.gib:g} GiB in {seconds:.2f} s ({args.gib / seconds:.2f} GiB/s)", flush=True)
        del array


if __name__ == "__main__":
    main()
