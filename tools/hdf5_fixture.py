"""An HDF5 demo file written by h5py, for tests/test_cli_convert.py: `convert` must say it does
not read HDF5 (and how to get such data in), not ask for a --from that cannot read it.

Run with an interpreter that has h5py (never a project dependency):

    python3.12 -m venv /tmp/h5venv && /tmp/h5venv/bin/pip install h5py
    /tmp/h5venv/bin/python tools/hdf5_fixture.py

It writes tests/fixtures/formats/robomimic-layout.hdf5: two MountainCar-v0 episodes of a
scripted pusher in robomimic's layout (`data/demo_K/obs/state`, `actions`, `rewards`, `dones`),
the layout most HDF5 demo sets follow.
"""

from __future__ import annotations

import math
from pathlib import Path

import h5py
import numpy as np

OUT = Path(__file__).resolve().parent.parent / "tests" / "fixtures" / "formats" / "robomimic-layout.hdf5"


def episode(start: float, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """MountainCar-v0's dynamics under a pusher that pushes along the velocity."""
    position, velocity, states, actions = start, 0.0, [], []
    for _ in range(steps):
        action = 2 if velocity >= 0 else 0
        states.append((position, velocity))
        actions.append(action)
        velocity = min(max(velocity + (action - 1) * 0.001 - 0.0025 * math.cos(3 * position), -0.07), 0.07)
        position = min(max(position + velocity, -1.2), 0.6)
    return np.array(states, np.float32), np.array(actions, np.int64)


def main() -> None:
    with h5py.File(OUT, "w") as file:
        data = file.create_group("data")
        data.attrs["env"] = "MountainCar-v0"
        for k, start in enumerate((-0.5, -0.45)):
            states, actions = episode(start, 20)
            demo = data.create_group(f"demo_{k}")
            demo.attrs["num_samples"] = len(actions)
            demo.create_dataset("obs/state", data=states)
            demo.create_dataset("actions", data=actions)
            demo.create_dataset("rewards", data=np.full(len(actions), -1.0))
            demo.create_dataset("dones", data=np.zeros(len(actions), np.int64))
    print(f"wrote {OUT} ({OUT.stat().st_size} bytes)")


if __name__ == "__main__":
    main()
