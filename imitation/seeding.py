"""One seed for every generator a job draws from."""

from __future__ import annotations

import random

from imitation.errors import ImitationError

# numpy's legacy generator takes seeds in [0, 2^32), torch's in [0, 2^64): a seed a user gives
# stays in the first, with room above it for the seeds a job derives from it (episode i of a seed
# S is reset with S + i, an apprenticeship iteration k seeds with S + 1000 k).
SEED_BOUND = 2**32


def seed_problem(seed: int) -> str | None:
    """What is wrong with a seed a user gives, or None."""
    return None if 0 <= seed < SEED_BOUND else f"must be a whole number from 0 to {SEED_BOUND - 1}, got {seed}"


def seed_everything(seed: int) -> None:
    """Seed Python's, numpy's global and torch's generators. Jobs call it before they build
    anything random (networks, splits, environments), so a run is a function of its seed."""
    import numpy as np
    import torch

    if seed < 0:
        raise ImitationError(f"seed must be a whole number from 0 to {SEED_BOUND - 1}, got {seed}")
    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed % 2**64)
