"""A private local Ray for the Ray workers' tests of this folder, started once per module."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

import imitation


@pytest.fixture(scope="module")
def local_ray():
    """Ray of 2 CPUs whose workers import the `imitation` package this process imported: Ray's
    workers otherwise import it from wherever Python finds it, which under mutation testing is the
    unmutated source rather than mutants/ (and a mutant's actor class then fails to unpickle)."""
    from imitation.ray_engine import ray_session

    package_parent = str(Path(imitation.__file__).resolve().parent.parent)
    before = os.environ.get("PYTHONPATH")
    os.environ["PYTHONPATH"] = os.pathsep.join(filter(None, [package_parent, before]))
    try:
        with ray_session(num_cpus=2) as session:
            yield session
    finally:
        if before is None:
            del os.environ["PYTHONPATH"]
        else:
            os.environ["PYTHONPATH"] = before
