"""Turn the partial file of an interrupted or failed write into a proper demo file.

A writer killed, interrupted by a full disk or stopped by an error leaves `F.mcap.partial`
holding every episode it had finished. `recover_partial` reads those episodes with the salvage
scan and writes them, bit-exact, to a new demo file (by default `F.mcap`); the partial file is
removed afterwards when nothing beyond an unfinished tail was lost, and kept otherwise.
"""

from __future__ import annotations

import os
from contextlib import ExitStack
from pathlib import Path
from typing import Any

from imitation.data.mcap.format import DEFAULT_COMPRESSION
from imitation.data.mcap.reader import DemoFile
from imitation.data.mcap.source import refuse_url
from imitation.data.mcap.writer import DemoWriter
from imitation.errors import ImitationError
from imitation.output import OutputLock

PARTIAL_SUFFIX = ".partial"
# What the salvage scan reports when only the unfinished end of the file is missing.
_TAIL_ONLY = ("truncated", "an incomplete episode after the last complete one")


def recover_partial(
    partial: str | os.PathLike, out: str | os.PathLike | None = None, *, compression: str = DEFAULT_COMPRESSION
) -> dict[str, Any]:
    """Write the complete episodes of `partial` to `out` (default: its name without
    `.partial`) and describe what was recovered."""
    for given in (partial, out):  # it writes `out` and removes `partial`
        if given is not None:
            refuse_url(given)
    partial = Path(partial)
    if out is None:
        if not partial.name.endswith(PARTIAL_SUFFIX) or partial.name == PARTIAL_SUFFIX:
            raise ImitationError(f"{partial}: not named F{PARTIAL_SUFFIX}; give --out for the recovered file")
        out = partial.with_name(partial.name[: -len(PARTIAL_SUFFIX)])
    out = Path(out)
    if os.path.lexists(out):
        raise ImitationError(f"--out {out}: exists; recovering never replaces a file (choose another --out)")
    # The writer that made the partial file held the lock on its target while it ran: a
    # partial file still being written is refused here.
    writer_target = (
        partial.with_name(partial.name[: -len(PARTIAL_SUFFIX)]) if partial.name.endswith(PARTIAL_SUFFIX) else partial
    )
    with ExitStack() as locks:
        for target in dict.fromkeys([writer_target, out]):
            locks.enter_context(OutputLock(target))
        source = DemoFile(partial, salvage=True)
        if len(source) == 0:
            raise ImitationError(f"{partial}: holds no complete episode; nothing to recover ({source.damage or 'empty'})")
        writer = DemoWriter(
            out,
            env_id=source.env_id,
            observation_space=source.observation_space,
            action_space=source.action_space,
            dt=source.dt,
            source=source.source,
            metadata=source.user_metadata,
            end_flags=source.end_flags,
            compression=compression,
            finite_only=False,
            temporary=out.with_name(f".{out.name}.recovering"),
            lock=False,
        )
        with writer:
            for episode in source:
                writer.write(episode)
        damage = source.damage
        removed = damage is None or damage.startswith(_TAIL_ONLY)
        if removed:
            partial.unlink()
    return {
        "partial": str(partial),
        "out": str(out),
        "episodes": len(source),
        "transitions": source.num_transitions,
        "lost": damage,
        "partial_removed": removed,
    }
