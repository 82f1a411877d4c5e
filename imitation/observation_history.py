"""The observations a sequence policy acts on: the n latest of each env of a batch, newest last.
Before an episode's n-th step its first observation stands in for the missing ones, as the
windows it was trained on pad them (`imitation.data.windows`)."""

from __future__ import annotations

import numpy as np


class ObservationHistory:
    """The n latest flat observations of each row; `push` adds a step's, `clear` starts an episode."""

    def __init__(self, length: int) -> None:
        self.length = length
        self.rows: np.ndarray | None = None  # (batch, n, features)

    def push(self, observations: np.ndarray) -> bool:
        """Add the current observations (a batch of any shape, flattened per row); True when a new
        episode (or a batch of another size) started the history afresh."""
        current = np.asarray(observations, dtype=np.float32).reshape(len(observations), -1)
        if self.rows is None or len(self.rows) != len(current):
            self.rows = np.repeat(current[:, None], self.length, axis=1)
            return True
        self.rows = np.concatenate([self.rows[:, 1:], current[:, None]], axis=1)
        return False

    def clear(self) -> None:
        self.rows = None
