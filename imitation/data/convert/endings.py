"""Why each converted episode ended: terminated (a terminal state, no bootstrapping past it) or
truncated (cut short: a time limit, a recording that stops).

Many sources cannot tell the two apart. HumanCompatibleAI/imitation's `terminal` is True at every
trajectory end, time limits included; stable-baselines' GAIL npz and bare arrays say nothing;
gymnasium's old `done` merged both. A converter describes what its source says with `SourceEnds`,
and `settle_ends` decides, once the env is known:

- with an env that has a time limit (`max_episode_steps`): a source episode that took exactly
  that many steps ended at the limit (truncated); a shorter one ended in a terminal state
  (terminated); a longer one cannot come from that env's limit, and is refused.
- without one: the source's flags are kept as they are, the file says they are the source's (a
  time limit may be marked as a termination), and the conversion warns.

Layouts without final observations (stable-baselines' GAIL npz, arrays whose rows hold s_t and
a_t but not the state after the last action) keep every episode's observations up to the one the
last action was *taken* in: the demo then stops one step before the source's episode ended, its
final observation is not terminal, and the episode is truncated whatever the reason the source's
episode ended; that reason, when decided, is kept in each episode's metadata as `source_end`.

What was decided is written to the demo file's dataset metadata as `end_flags` (docs/FORMAT.md
§3.1) and shown by `imitation info`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from imitation.errors import ImitationError

if TYPE_CHECKING:
    from imitation.data.convert.converted import Converted

# `end_flags["decided"]`: how the flags were decided.
ENV = "env"  # the env's own terminated/truncated signals (record, DAgger)
TIME_LIMIT = "time_limit"  # from the env's time limit
SOURCE = "source"  # the source's flag, kept: it may count a time limit as a termination
UNKNOWN = "unknown"  # the source does not say why episodes ended
LAYOUT = "layout"  # stated by the layout of a bare array (`ends: terminated` or `truncated`)
TERMINAL_STATE = "terminal_state"  # cut where the env's termination rule first holds (terminal_states.py)
RECORDING = "recording"  # a recording (a ROS bag) stops where its recorder stopped: every episode truncated


@dataclass(frozen=True)
class SourceEnds:
    """What a source says about its episodes' ends, one entry per converted episode.

    `done[k]`: the source marks episode k as ended by the env (True), or as cut off by the
    recorder (False, kept as truncated); None when the source does not say (stable-baselines).
    `steps[k]`: env steps the source's episode took (its actions, including any the conversion
    drops). `final_observation`: the demos keep the observation each episode ended in.
    `flag`: the source's name for it, for messages (`terminal`, `episode_starts`, ...)."""

    flag: str
    steps: list[int]
    done: list[bool] | None
    final_observation: bool
    needs_limit: str | None = None  # what asks for a time limit, when keeping the source's flags is no answer

    def __post_init__(self) -> None:
        if self.done is None and self.final_observation:
            raise ValueError("a source that keeps final observations must say which episodes the env ended")


def settle_ends(converted: Converted) -> Converted:
    """`converted` with every episode's flags decided from `converted.ends`, its `end_flags`
    saying how, and a warning where they could not be decided. Sources that tell time limits
    from terminations (`ends` None) are returned as they are."""
    ends = converted.ends
    if ends is None:
        return converted
    episodes, warnings = list(converted.episodes), list(converted.warnings)
    limit = converted.max_episode_steps if converted.env_id else None
    flags: dict[str, Any] = {"decided": UNKNOWN if ends.done is None else SOURCE, "source_flag": ends.flag}
    if not ends.final_observation:
        flags["final_observation"] = False
    if limit is not None:
        flags.update(decided=TIME_LIMIT, env_id=converted.env_id, max_episode_steps=limit)
        source_ends = []
        for k, steps in enumerate(ends.steps):
            if ends.done is not None and not ends.done[k]:
                source_ends.append("cut")  # the source says the recorder stopped it: truncated, whatever its length
                continue
            if steps > limit:
                raise ImitationError(
                    f"{converted.source}: episode {k} took {steps} steps, more than {converted.env_id}'s time limit of "
                    f"{limit}; its end cannot be decided from that limit (convert without --env to keep the source's flags)"
                )
            source_ends.append("time_limit" if steps == limit else "terminated")
        for k, end in enumerate(source_ends):
            terminated = end == "terminated" and ends.final_observation
            metadata = episodes[k].metadata if ends.final_observation else {**episodes[k].metadata, "source_end": end}
            episodes[k] = dataclasses.replace(episodes[k], terminated=terminated, truncated=not terminated, metadata=metadata)
        if not ends.final_observation:
            flags["source_terminated"] = source_ends.count("terminated")
            flags["source_time_limit"] = source_ends.count("time_limit")
    else:
        if converted.env_id:
            reason = f"{converted.env_id} has no time limit"
            flags["env_id"] = converted.env_id
        else:
            reason = "no --env was given"
        if ends.needs_limit is not None:
            raise ImitationError(
                f"{converted.source}: {ends.needs_limit} decides each episode's end from the env's time limit, and "
                f"{reason}; give --env ID of an env with a time limit, or state the ends (ends: terminated or truncated)"
            )
        if ends.final_observation and ends.done is not None:
            warnings.append(
                f"{converted.source}: the end flags are the source's ({ends.flag}), which cannot tell a time limit from a "
                f"termination; {reason}, so they are kept: {sum(e.terminated for e in episodes)} episode(s) marked "
                "terminated may have ended at a time limit (convert with --env ID to decide from its time limit)"
            )
        else:
            warnings.append(
                f"{converted.source}: the source does not say whether its episodes ended in a terminal state or at a time "
                f"limit ({reason}); each demo stops one step before its episode ended, so all are truncated"
            )
    flags["terminated"] = sum(e.terminated for e in episodes)
    flags["truncated"] = sum(e.truncated for e in episodes)
    return dataclasses.replace(converted, episodes=episodes, warnings=warnings, end_flags=flags, ends=None)


def recording_end_flags(converted: Converted) -> Converted:
    """`converted`, a recording whose episodes stop where the recorder stopped, with `end_flags` saying so."""
    episodes = converted.episodes
    flags = {
        "decided": RECORDING,
        "terminated": sum(e.terminated for e in episodes),
        "truncated": sum(e.truncated for e in episodes),
    }
    return dataclasses.replace(converted, end_flags=flags)


def describe_end_flags(flags: dict[str, Any] | None) -> str:
    """One line for `imitation info`: how the file's terminated/truncated flags were decided."""
    if flags is None:
        return "not recorded (written before imitation-mcap kept how end flags were decided)"
    decided = flags.get("decided")
    source_flag = flags.get("source_flag", "its flag")
    if decided == ENV:
        return "the env's own terminated/truncated signals"
    if decided == TIME_LIMIT:
        limit = f"{flags.get('env_id')}'s {flags.get('max_episode_steps')}-step time limit"
        if flags.get("final_observation") is False:
            return (
                f"all truncated: the source keeps no final observation, so each demo stops one step before its episode "
                f"ended; decided from {limit}, the source's episodes ended {flags.get('source_terminated')} terminated, "
                f"{flags.get('source_time_limit')} at the limit (episode metadata source_end)"
            )
        return (
            f"decided from {limit} (the source's `{source_flag}` does not tell one from a termination): episodes of "
            f"{flags.get('max_episode_steps')} steps truncated, shorter ones terminated"
        )
    if decided == SOURCE:
        return (
            f"the source's `{source_flag}`, kept as it is: it cannot tell a time limit from a termination, so time-limited "
            "episodes may be marked terminated (convert with --env to decide from the env's time limit)"
        )
    if decided == LAYOUT:
        if flags.get("final_observation") is False:
            return (
                f"all truncated: each demo stops one step before its episode ended; the layout states its episodes "
                f"ended {flags.get('layout_ends')} (episode metadata source_end)"
            )
        return f"as the conversion's layout states (ends: {flags.get('layout_ends')})"
    if decided == RECORDING:
        return f"all {flags.get('truncated')} truncated: a recording stops where its recorder stopped, not in a terminal state"
    if decided == TERMINAL_STATE:
        return (
            f"each episode ends where {flags.get('env_id')}'s termination rule first holds on its recorded states "
            f"({flags.get('terminated')} terminated there, {flags.get('steps_cut')} steps recorded after it cut; "
            f"{flags.get('truncated')} truncated, never reaching one)"
        )
    if decided == UNKNOWN:
        return (
            "the source does not say why episodes ended; all truncated: each demo stops one step before its episode ended "
            "(convert with --env to record, per episode, whether it ended at the time limit)"
        )
    return f"{decided}"
