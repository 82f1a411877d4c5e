"""docs/ERRORS.md is complete and true: every `raise ImitationError(...)` in the package has its
message there; every entry marked CLI is triggered here through the command line (one case per
entry at least, table-driven, all run in one process with run_cli_many), which must exit 1 with one
line on stderr that matches the entry's message (and, where the entry's `{flag}` stands for the flag
the command line names, starts with that flag); every other entry says which test triggers it or
why the command line cannot."""

from __future__ import annotations

import base64
import dataclasses
import io
import json
import os
import re
import shutil
import struct
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import gymnasium as gym
import numpy as np
import pytest
import torch
import yaml
from error_sites import error_sites, normalise, pattern_regex
from sb3_zips import sb3_weights, space_entry
from support import DATASETS, REPO, TESTDATA, TURTLE_MAP, run_cli_many, write_map

DOC = REPO / "docs" / "ERRORS.md"
# Printed by cli.py itself (cli-3, cli-4), or appended by the run directory to the error that stopped a run (out-11).
NOT_RAISED = {"cli-3", "cli-4", "out-11"}


@dataclass(frozen=True)
class Entry:
    id: str
    template: str
    test: str


def catalogue() -> dict[str, Entry]:
    entries = {}
    for line in DOC.read_text().splitlines():
        row = re.match(r"\| ([a-z0-9-]+) \| (.*?) \| .* \| ([^|]*) \|$", line)
        if row is None or row[1] == "ID":
            continue
        code = re.match(r"``\s?(.+?)\s?``|`([^`]+)`", row[2])
        assert code, f"{row[1]}: no message in backticks"
        assert row[1] not in entries, f"{row[1]} twice"
        entries[row[1]] = Entry(row[1], code[1] or code[2], row[3].strip())
    return entries


ENTRIES = catalogue()


def test_every_raised_message_is_in_the_catalogue() -> None:
    sources = sorted((REPO / "imitation").rglob("*.py")) + [REPO / "cli.py"]
    sites = error_sites(sources, REPO)
    assert len(sites) > 250
    listed = {normalise(entry.template) for entry in ENTRIES.values()}
    missing = [f"{s.path}:{s.line}: {s.template}" for s in sites if normalise(s.template) not in listed]
    assert not missing, "messages raised but not in docs/ERRORS.md:\n" + "\n".join(missing)
    raised = {normalise(s.template) for s in sites}
    stale = [e.id for e in ENTRIES.values() if e.id not in NOT_RAISED and normalise(e.template) not in raised]
    assert not stale, f"entries whose message is raised nowhere: {stale}"


def test_every_entry_says_how_it_is_tested() -> None:
    for entry in ENTRIES.values():
        if entry.test == "CLI":
            assert entry.id in CASES, f"{entry.id} is marked CLI but has no case here"
        elif entry.test.startswith("CLI ("):
            name = entry.test.removeprefix("CLI (").split(")")[0].split(";")[0].strip()
            if not name.startswith("same template"):
                assert (REPO / name).is_file(), f"{entry.id}: {name} does not exist"
        elif (same := re.fullmatch(r"not from the CLI: as ([a-z0-9-]+)", entry.test)) is not None:
            assert ENTRIES[same[1]].test.startswith("not from the CLI: "), f"{entry.id}: refers to {same[1]}, which is tested from the CLI"
        else:
            assert re.match(r"not from the CLI: \S.{10,}", entry.test), f"{entry.id}: '{entry.test}' gives no reason"
    assert set(CASES) <= set(ENTRIES), set(CASES) - set(ENTRIES)
    assert len({c.name for c in CASE_LIST}) == len(CASE_LIST), "two cases of one name: give one a variant"
    for c in CASE_LIST:
        for entry_id in c.ids:
            if ENTRIES[entry_id].template.startswith("{flag}"):
                # The placeholder matches any field name: the case says which flag the CLI must put there.
                assert c.expect.startswith("--"), f"{c.name}: {entry_id}'s message names a flag; say which in expect"


# ------------------------------------------------------------------------------------------------
# Inputs the cases need, built in one temporary folder


class Inputs:
    def __init__(self, root: Path) -> None:
        self.root = root

    def path(self, name: str) -> Path:
        path = self.root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        return path

    def text(self, name: str, content: str) -> Path:
        path = self.path(name)
        path.write_text(content)
        return path

    def folder(self, name: str) -> Path:
        path = self.root / name
        path.mkdir(parents=True, exist_ok=True)
        return path

    # -- demo files ---------------------------------------------------------------------------

    def demo_with(self, name: str, source: str = "CartPole-v1.mcap", *, dataset: Callable[[dict], dict] | None = None, crc: bool = True,
                  message: Callable[[int, bytes], bytes] | None = None, episodes: Callable[[list], list] | None = None) -> Path:
        """A bundled demo file written again record by record, its dataset metadata or its
        episode index edited (checksum recomputed unless crc=False) or one block message's
        bytes changed."""
        from mcap.records import Channel, Header, Message, Metadata, Schema
        from mcap.stream_reader import StreamReader
        from mcap.writer import Writer

        from imitation.data.mcap.format import DATASET_METADATA, EPISODES_METADATA, metadata_crc

        records = [r for r in StreamReader(io.BytesIO((DATASETS / source).read_bytes()), emit_chunks=False).records]
        header = next(r for r in records if isinstance(r, Header))
        out = io.BytesIO()
        writer = Writer(out)
        writer.start(profile=header.profile, library=header.library)
        seen: set = set()
        index = 0
        for record in records:
            if isinstance(record, Metadata):
                if record.name in seen:
                    continue
                seen.add(record.name)
                values = dict(record.metadata)
                if record.name == DATASET_METADATA and dataset is not None:
                    values = dataset({k: v for k, v in values.items() if k != "crc32"})
                    values["crc32"] = metadata_crc(values) if crc else "0"
                if record.name == EPISODES_METADATA and episodes is not None:
                    values = {"episodes": json.dumps(episodes(json.loads(values["episodes"])))}
                    values["crc32"] = metadata_crc(values)
                writer.add_metadata(record.name, values)
            elif isinstance(record, (Schema, Channel)):
                if (type(record), record.id) in seen:
                    continue
                seen.add((type(record), record.id))
                if isinstance(record, Schema):
                    writer.register_schema(record.name, record.encoding, record.data)
                else:
                    writer.register_channel(record.topic, record.message_encoding, record.schema_id, dict(record.metadata))
            elif isinstance(record, Message):
                data = message(index, record.data) if message is not None else record.data
                index += 1
                writer.add_message(record.channel_id, log_time=record.log_time, data=data, publish_time=record.publish_time)
        writer.finish()
        path = self.path(name)
        path.write_bytes(out.getvalue())
        return path

    def episodes_file(self, name: str, episodes: list, source: str, **options) -> Path:
        from imitation.data.mcap.reader import DemoFile
        from imitation.data.mcap.writer import write_episodes

        demo = DemoFile(DATASETS / source)
        return write_episodes(self.path(name), episodes, env_id=demo.env_id, observation_space=demo.observation_space,
                              action_space=demo.action_space, **options)

    def truncated(self, name: str, fraction: float = 0.5) -> Path:
        data = (DATASETS / "CartPole-v1.mcap").read_bytes()
        path = self.path(name)
        path.write_bytes(data[: int(len(data) * fraction)])
        return path

    def cut_at_record(self, name: str, offset_into_record: int) -> Path:
        """CartPole's demos (written one chunk per episode) cut a few bytes into their third chunk."""
        data = (DATASETS / "CartPole-v1.mcap").read_bytes()
        at, chunks = 8, []
        while at + 9 <= len(data):
            if data[at] == 0x06:
                chunks.append(at)
            at += 9 + struct.unpack_from("<Q", data, at + 1)[0]
        path = self.path(name)
        path.write_bytes(data[: chunks[2] + offset_into_record])
        return path

    def flipped_summary(self, name: str) -> Path:
        data = bytearray((DATASETS / "CartPole-v1.mcap").read_bytes())
        (summary_start,) = struct.unpack_from("<Q", data, len(data) - 8 - 20)
        data[summary_start + 20] ^= 0x40
        path = self.path(name)
        path.write_bytes(bytes(data))
        return path

    def patched(self, name: str, patch: Callable[[bytearray, int, int], None]) -> Path:
        """CartPole's demos with bytes changed by patch(data, summary_start, first chunk's offset);
        the footer's summary checksum is zeroed (MCAP: not checked) so the summary may change."""
        data = bytearray((DATASETS / "CartPole-v1.mcap").read_bytes())
        (summary_start,) = struct.unpack_from("<Q", data, len(data) - 28)
        data[len(data) - 12 : len(data) - 8] = b"\0\0\0\0"
        at = 8
        while data[at] != 0x06:
            at += 9 + struct.unpack_from("<Q", data, at + 1)[0]
        patch(data, summary_start, at)
        path = self.path(name)
        path.write_bytes(bytes(data))
        return path

    @staticmethod
    def chunk_index(data: bytearray, summary_start: int) -> tuple[int, int]:
        """(start, end) of the first chunk index record's body in the summary."""
        at = summary_start
        while data[at] != 0x08:
            at += 9 + struct.unpack_from("<Q", data, at + 1)[0]
        return at + 9, at + 9 + struct.unpack_from("<Q", data, at + 1)[0]

    def flipped_chunk(self, name: str) -> Path:
        """Uncompressed demos with one bit flipped in the middle of the data: a CRC mismatch."""
        from imitation.data.mcap.reader import DemoFile

        source = self.episodes_file(name + ".src.mcap", DemoFile(DATASETS / "CartPole-v1.mcap").read_episodes(), "CartPole-v1.mcap", compression="none")
        data = bytearray(source.read_bytes())
        data[len(data) // 3] ^= 0x10
        path = self.path(name)
        path.write_bytes(bytes(data))
        return path

    # -- runs ---------------------------------------------------------------------------------

    def policy_run(self, name: str, *, config: Callable[[dict], dict] | None = None, weights: Callable[[dict], dict] | None = None,
                   kind: str = "bc", spaces: tuple = None) -> Path:
        from imitation.policies import make_policy, policy_tensors
        from imitation.runs import RunWriter

        spaces = spaces or (gym.spaces.Box(-np.inf, np.inf, (4,), np.float32), gym.spaces.Discrete(2))
        policy = make_policy(*spaces, hidden_sizes=[8])
        settings = {"kind": kind, "env_id": "CartPole-v1", "policy": policy.config.to_json()}
        with RunWriter(self.root / name, config=config(settings) if config else settings, tensorboard=False) as run:
            tensors = policy_tensors(policy)
            run.save_weights(weights(tensors) if weights else tensors)
            run.finish({})
        return self.root / name

    def reward_run(self, name: str, *, config: Callable[[dict], dict] | None = None, weights: Callable[[dict], dict] | None = None,
                   demos: bool = True) -> Path:
        from imitation.rewards import make_reward_model, reward_tensors
        from imitation.runs import RunWriter

        model = make_reward_model(gym.spaces.Box(-np.inf, np.inf, (4,), np.float32), gym.spaces.Discrete(2), hidden_sizes=[8])
        settings = {"kind": "reward", "env_id": "CartPole-v1", "reward": model.config.to_json(), "irl": {"method": "gcl"}}
        if demos:
            settings["demos"] = [str(DATASETS / "CartPole-v1.mcap")]
        with RunWriter(self.root / name, config=config(settings) if config else settings, tensorboard=False) as run:
            tensors = reward_tensors(model)
            run.save_weights(weights(tensors) if weights else tensors)
            run.finish({})
        return self.root / name

    def interrupted_ppo(self, name: str, steps: int = 4096, *, tensors: dict | None = None, state: dict | None = None) -> Path:
        """RUN_DIR.partial of a `train ppo --env CartPole-v1 --steps STEPS` stopped after a checkpoint."""
        from imitation.jobs.presets import ppo_config
        from imitation.runs import RunWriter

        config = ppo_config("CartPole-v1", total_steps=steps)
        with pytest.raises(KeyboardInterrupt):
            with RunWriter(self.root / name, config={"kind": "ppo", "env_id": "CartPole-v1", "creator": "x", "ppo": vars(config)}, tensorboard=False) as run:
                run.save_checkpoint(tensors if tensors is not None else {"x": torch.zeros(1)}, state if state is not None else {"update": 1})
                raise KeyboardInterrupt
        return self.root / name

    # -- sb3 zips -----------------------------------------------------------------------------

    def sb3_zip(self, name: str, *, weights: dict | None = None, data: dict | None = None, members: dict | None = None,
                observation: gym.Space | None = None, action: gym.Space | None = None) -> Path:
        if weights is None:
            weights = sb3_weights(4, 2, pi=[8], vf=[8])
        buffer = io.BytesIO()
        torch.save(weights, buffer)
        fields = {"observation_space": space_entry(observation or gym.spaces.Box(-np.inf, np.inf, (4,), np.float32)),
                  "action_space": space_entry(action or gym.spaces.Discrete(2)), "policy_kwargs": {}, "use_sde": False} | (data or {})
        path = self.path(name)
        with zipfile.ZipFile(path, "w") as archive:
            for member, content in (members if members is not None else {"data": json.dumps(fields).encode(), "policy.pth": buffer.getvalue()}).items():
                archive.writestr(member, content)
        return path

    # -- converter sources --------------------------------------------------------------------

    def npz(self, name: str, **arrays) -> Path:
        path = self.path(name)
        with open(path, "wb") as stream:
            np.savez(stream, **arrays)
        return path

    def sb_npz(self, name: str, **changes) -> Path:
        rows = 6
        arrays = {"obs": np.zeros((rows, 4), np.float32), "actions": np.zeros((rows, 1), np.int64), "rewards": np.ones(rows),
                  "episode_starts": np.array([1, 0, 0, 1, 0, 0], bool)}
        return self.npz(name, **{**arrays, **changes})

    def imitation_npz(self, name: str, **changes) -> Path:
        arrays = {"obs": np.zeros((8, 4), np.float32), "acts": np.zeros(6, np.int64), "indices": np.array([3]), "terminal": np.array([True, False]),
                  "rews": np.ones(6)}
        return self.npz(name, **{**arrays, **changes})

    def lerobot(self, name: str, *, info: Callable[[dict], dict] | None = None, episodes: str | None = None, drop: tuple[str, ...] = ()) -> Path:
        """The first two episodes of the G1 v2.1 dataset, edited."""
        source = TESTDATA / "lerobot" / "g1_v21"
        root = self.folder(name)
        (root / "meta").mkdir()
        data = json.loads((source / "meta" / "info.json").read_text())
        lines = (source / "meta" / "episodes.jsonl").read_text().splitlines()[:2]
        data.update(total_episodes=2, total_frames=sum(json.loads(line)["length"] for line in lines))
        (root / "meta" / "info.json").write_text(json.dumps(info(data) if info else data))
        (root / "meta" / "episodes.jsonl").write_text(episodes if episodes is not None else "\n".join(lines) + "\n")
        (root / "meta" / "tasks.jsonl").write_text((source / "meta" / "tasks.jsonl").read_text())
        for index in range(2):
            relative = f"data/chunk-000/episode_{index:06d}.parquet"
            if relative not in drop:
                (root / relative).parent.mkdir(parents=True, exist_ok=True)
                shutil.copy(source / relative, root / relative)
        for relative in drop:
            if (root / relative).is_file():
                (root / relative).unlink()
        return root

    def turtle_map(self, name: str, **changes) -> Path:
        """The turtlesim map with `changes` (a key set to None is left out)."""
        data = {**TURTLE_MAP, **changes}
        return write_map(self.root, {k: v for k, v in data.items() if v is not None}, name)

    def entry_map(self, name: str, **entry) -> Path:
        """The turtle map with its observation entry edited."""
        return self.turtle_map(name, observation=[{"topic": "/turtle1/pose", "fields": ["x"], **entry}])


TURTLE = TESTDATA / "ros1" / "plotjuggler_example.bag"


def _cartpole_episodes():
    from imitation.data.mcap.reader import DemoFile

    return DemoFile(DATASETS / "CartPole-v1.mcap").read_episodes([0, 1])


def _grid(edit: Callable) -> Callable[[Inputs], list]:
    def build(i: Inputs) -> list:
        from imitation.data.mcap.reader import DemoFile

        episodes = DemoFile(DATASETS / "GridWorld8x8-v0.mcap").read_episodes([0, 1, 2])
        path = i.episodes_file(f"grid-{edit.__name__}.mcap", edit(episodes), "GridWorld8x8-v0.mcap")
        return ["train", "irl", "--method", "mce", "--env", "imitation/GridWorld8x8-v0", "--demos", path, "--iterations", "3", "--quiet", "--out", i.root / "irl-run"]

    return build


def _state_99(episodes):
    observations = np.array(episodes[0].observations)
    observations[2] = 99
    return [dataclasses.replace(episodes[0], observations=observations), *episodes[1:]]


def _too_long(episodes):
    first, second = episodes[0], episodes[1]
    return [dataclasses.replace(first, observations=np.concatenate([first.observations, second.observations[1:]]),
                                actions=np.concatenate([first.actions, second.actions]), rewards=np.concatenate([first.rewards, second.rewards]))]


def _bc(demos, *extra) -> list:
    """`train bc` on CartPole; without --out, the run goes beside the (generated) last demo file."""
    demos = demos if isinstance(demos, list) else [demos]
    out = [] if "--out" in extra else ["--out", Path(str(demos[-1]) + ".run")]
    assert out == [] or REPO not in Path(out[1]).parents, "no run directory inside the repository"
    return ["train", "bc", "--demos", *demos, "--env", "CartPole-v1", "--epochs", "1", "--quiet", *extra, *out]


def _sb3(path: Path) -> list:
    return ["record", "--env", "CartPole-v1", "--expert", f"sb3:{path}", "--episodes", "1", "--quiet", "--out", path.with_suffix(".mcap")]


def _convert(source, *extra, out: str | None = "out.mcap") -> list:
    return ["convert", source, *extra, *(["--out", Path(source).parent / out] if out else [])]


def _map_case(name: str, **changes) -> Callable[[Inputs], list]:
    return lambda i: _convert(TURTLE, "--map", i.turtle_map(name, **changes))


def _entry_case(name: str, **entry) -> Callable[[Inputs], list]:
    return lambda i: _convert(TURTLE, "--map", i.entry_map(name, **entry))


def _lerobot_case(name: str, **options) -> Callable[[Inputs], list]:
    return lambda i: _convert(i.lerobot(name, **options), "--from", "lerobot", out=None) + ["--out", i.root / f"{name}.mcap"]


def _npz_case(builder: str, name: str, *extra, **changes) -> Callable[[Inputs], list]:
    return lambda i: _convert(getattr(i, builder)(name, **changes), *extra)


# A bare (episodes, steps, [position, velocity, action]) array as MountainCar demos are shipped:
# rows hold s_t and a_t, the row after the last action the final state, NaN padding after it.
ARRAY = np.array([[[-0.5, 0.0, 2], [-0.49, 0.01, 2], [-0.48, 0.01, np.nan], [np.nan] * 3],
                  [[-0.5, 0.0, 0], [-0.51, -0.01, 0], [-0.52, -0.01, 0], [-0.53, -0.01, np.nan]]])
LAYOUT = {"observation": [0, 1], "action": [2], "discrete_action": True, "rows": "state", "reward": -1}


def _array_case(name: str, *extra, data: np.ndarray | None = None, layout: dict | str | None = None, **changes) -> Callable[[Inputs], list]:
    """`convert NAME.npy --layout NAME.yaml --env MountainCar-v0`, the array or layout changed."""
    def build(i: Inputs) -> list:
        path = i.path(f"{name}.npy")
        np.save(path, ARRAY if data is None else data)
        text = layout if isinstance(layout, str) else yaml.safe_dump({**LAYOUT, **(layout or {}), **changes})
        env = [] if "--no-env" in extra else ["--env", "MountainCar-v0"]
        return _convert(path, "--layout", i.text(f"{name}.yaml", text), *env, *(e for e in extra if e != "--no-env"))

    return build


def _pendulum_terminal_state(i: Inputs) -> list:
    """Pendulum keeps (θ, θ') and observes (cos θ, sin θ, θ'): its state cannot be set to an observation."""
    path = i.path("ts-pendulum.npy")
    np.save(path, np.zeros((2, 4, 4)))
    layout = {"observation": [0, 1, 2], "action": [3], "rows": "state", "reward": -1, "ends": "terminal_state"}
    return _convert(path, "--layout", i.text("ts-pendulum.yaml", yaml.safe_dump(layout)), "--env", "Pendulum-v1")


def _cut_npy(i: Inputs) -> list:
    path = i.path("cut.npy")
    np.save(path, ARRAY)
    path.write_bytes(path.read_bytes()[:-40])
    return _convert(path, "--layout", i.text("cut.yaml", yaml.safe_dump(LAYOUT)))


def _two_arrays(i: Inputs) -> list:
    return _convert(i.npz("two.npz", demos=ARRAY, seeds=np.arange(2)), "--layout", i.text("two.yaml", yaml.safe_dump(LAYOUT)))


def _index_field(offset: int, value: bytes) -> Callable[[bytearray, int, int], None]:
    """Overwrite bytes of the first chunk index: at `offset` into its body (negative: from its end)."""
    def patch(data: bytearray, summary_start: int, chunk: int) -> None:
        start, end = Inputs.chunk_index(data, summary_start)
        at = (start if offset >= 0 else end) + offset
        data[at : at + len(value)] = value

    return patch


def _nan_weights(tensors: dict) -> dict:
    return {name: torch.full_like(t, float("nan")) if t.is_floating_point() else t for name, t in tensors.items()}


def _npy_claiming_more(i: Inputs) -> list:
    member = io.BytesIO()
    np.lib.format.write_array_header_1_0(member, {"descr": "<f8", "fortran_order": False, "shape": (10**9,)})
    member.write(b"\0" * 64)
    path = i.path("claims.npz")
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("obs.npy", member.getvalue())
    return _convert(path)


def _sqlite_without_metadata(i: Inputs) -> list:
    folder = i.folder("db3-only")
    (folder / "x.db3").write_bytes(b"SQLite format 3\0")
    return _convert(folder, "--from", "ros2", "--map", i.turtle_map("m-db3.yaml"))


def _rosbag2_metadata(name: str, text: str) -> Callable[[Inputs], list]:
    def build(i: Inputs) -> list:
        folder = i.folder(name)
        (folder / "metadata.yaml").write_text(text)
        return _convert(folder, "--from", "ros2", "--inspect", out=None)

    return build


def _damaged_mcap_bag(i: Inputs) -> list:
    data = (TESTDATA / "ros2" / "replay_testing" / "cmd_vel_only_2.mcap").read_bytes()
    path = i.path("damaged-bag.mcap")
    path.write_bytes(data[: len(data) // 2])
    return _convert(path, "--from", "ros2", "--inspect", out=None)


def _lerobot_v30(name: str, edit: Callable[[Path], object]) -> Callable[[Inputs], list]:
    """The SO-101 v3.0 dataset (without its video, which the converter does not need), edited."""
    def build(i: Inputs) -> list:
        root = i.folder(name)
        shutil.copytree(TESTDATA / "lerobot" / "so101_v30", root, dirs_exist_ok=True, ignore=shutil.ignore_patterns("videos"))
        edit(root)
        return _convert(root, "--from", "lerobot", out=None) + ["--out", i.root / f"{name}.mcap"]

    return build


def _v30_data_file(root: Path) -> Path:
    return root / "data" / "chunk-000" / "file-000.parquet"


def _v30_without_rows(root: Path) -> None:
    import pyarrow.parquet as pq

    table = pq.read_table(_v30_data_file(root))
    pq.write_table(table.slice(0, 0), _v30_data_file(root))


def _cut_in_half(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def _checkpoint_case(name: str, **files) -> Callable[[Inputs], list]:
    """An interrupted PPO run whose partial folder's files are then replaced."""
    def build(i: Inputs) -> list:
        partial = Path(str(i.interrupted_ppo(name)) + ".partial")
        for relative, content in files.items():
            (partial / relative.replace("__", "/")).write_text(content)
        return ["train", "ppo", "--env", "CartPole-v1", "--steps", "4096", "--quiet", "--resume", "--out", i.root / name]

    return build


def _checkpoint_mismatch(prepare: list, name: str, trainer: dict) -> Callable[[Inputs], list]:
    """`prepare`'s command resumed from a partial run with its settings (copied from the
    finished run the first batch made) and a checkpoint that is not the trainer's."""
    def build(i: Inputs) -> list:
        from imitation.runs import save_checkpoint

        partial = i.folder(f"{name}-garbage.partial")
        shutil.copy(i.root / f"{name}-done" / "config.json", partial / "config.json")
        save_checkpoint(partial, {"x": torch.zeros(1)}, {"history": [], "trainer": trainer})
        return prepare + [i.root / f"{name}-garbage", "--resume"]

    return build


# Finished runs made before the cases, whose settings the checkpoint cases copy: command + --out.
PREPARE_BC = ["train", "bc", "--demos", str(DATASETS / "CartPole-v1.mcap"), "--env", "CartPole-v1", "--epochs", "1", "--hidden", "8", "--quiet", "--out"]
PREPARE_DAGGER = ["train", "dagger", "--env", "CartPole-v1", "--expert", "scripted", "--rounds", "1", "--episodes-per-round", "1", "--epochs", "1",
                  "--hidden", "8", "--quiet", "--out"]
PREPARE_IRL = ["train", "irl", "--method", "mce", "--env", "imitation/GridWorld8x8-v0", "--demos", str(DATASETS / "GridWorld8x8-v0.mcap"),
               "--iterations", "2", "--quiet", "--out"]


# Each case: the entries it triggers (the first, with its variant, is its name), a function
# building the argv, whether it needs ../shared/testdata, a variant (another way to the same entry),
# and text the message must contain besides (what the entry's placeholder is here: the flag the
# command line names for a config field, the trainer). The message must match every listed entry.
@dataclass(frozen=True)
class Case:
    ids: tuple[str, ...]
    argv: Callable[[Inputs], list]
    testdata: bool = False
    variant: str = ""
    expect: str = ""

    @property
    def name(self) -> str:
        return f"{self.ids[0]} ({self.variant})" if self.variant else self.ids[0]


def case(ids: str, argv: Callable[[Inputs], list], testdata: bool = False, *, variant: str = "", expect: str = "") -> Case:
    return Case(tuple(ids.split()), argv, testdata, variant, expect)


CASE_LIST = [
    # command line, environments, experts
    case("cli-1", lambda i: ["record", "--env", "CartPole-v1", "--episodes", "0", "--out", i.path("e.mcap")], expect="--episodes must"),
    case("cli-1", lambda i: ["eval", "policy", i.policy_run("e0"), "--env", "CartPole-v1", "--episodes", "0"], variant="eval policy",
         expect="--episodes must"),
    case("cli-2", lambda i: ["export", DATASETS / "CartPole-v1.mcap", "--to", "hdf5", i.path("x")]),
    case("cli-5", lambda i: ["record", "--env", "CartPole-v1", "--pixels", "84", "--out", i.path("c5.mcap")]),
    case("cli-6", lambda i: ["record", "--env", "CartPole-v1", "--pixels", "84x84", "--crop", "1,2,3", "--out", i.path("c6.mcap")]),
    case("cli-7", lambda i: ["record", "--env", "CartPole-v1", "--pixels", "84x84", "--crop", "0,0,0,5", "--out", i.path("c7.mcap")]),
    case("cli-8", lambda i: ["record", "--env", "CartPole-v1", "--action-noise", "2", "--out", i.path("c8.mcap")], expect="--action-noise must"),
    case("cli-8", lambda i: ["record", "--env", "CartPole-v1", "--action-noise", "0.2", "--noise-bias", "-1", "--out", i.path("c8b.mcap")],
         variant="bias", expect="--noise-bias must"),
    case("cli-10", lambda i: ["record", "--env", "CartPole-v1", "--noise-bias", "0.5", "--out", i.path("c10.mcap")], expect="--noise-bias biases"),
    case("cli-4 demo-d13", lambda i: ["info", i.cut_at_record("cut-header.mcap", 4)]),
    case("env-1", lambda i: ["record", "--env", "NoSuchEnv-v0", "--out", i.path("n.mcap")]),
    case("env-3", lambda i: ["train", "irl", "--method", "mce", "--env", "CartPole-v1", "--demos", DATASETS / "CartPole-v1.mcap", "--out", i.root / "irl-cp"]),
    case("env-8", lambda i: ["record", "--env", "CartPole-v1", "--pixels", "8x8", "--crop", "0,0,1000,1000", "--episodes", "1", "--quiet",
                             "--out", i.path("e8.mcap")]),
    case("expert-1", lambda i: ["record", "--env", "CartPole-v1", "--expert", "oracle", "--out", i.path("o.mcap")]),
    case("expert-2", lambda i: ["record", "--env", "Acrobot-v1", "--expert", "scripted", "--out", i.path("a.mcap")]),
    case("expert-3", lambda i: ["record", "--env", "Pendulum-v1", "--expert", "keyboard", "--out", i.path("k.mcap")]),
    case("expert-8", lambda i: ["train", "dagger", "--env", "CartPole-v1", "--expert", "gamepad", "--out", i.root / "e8"]),
    case("expert-10", lambda i: ["train", "dagger", "--env", "Pendulum-v1", "--expert", "standin", "--out", i.root / "e10"]),
    case("dagger-5", lambda i: ["train", "dagger", "--env", "CartPole-v1", "--expert", "scripted", "--mode", "takeover", "--out", i.root / "d4"],
         expect="--mode takeover needs"),
    case("cli-9", lambda i: ["info", i.folder("not-a-run")]),
    case("train-46", lambda i: _bc(DATASETS / "CartPole-v1.mcap", "--steps", "human", "--out", i.root / "t46")),
    case("train-48", lambda i: _bc(DATASETS / "CartPole-v1.mcap", "--steps", "human", "--stream-memory", "64", "--out", i.root / "t48"),
         expect="--steps human reads"),
    # demo files
    case("demo-1", lambda i: ["info", i.root / "absent.mcap"]),
    case("demo-2", lambda i: ["info", i.text("notes.mcap", "not mcap at all\n")]),
    case("demo-3", lambda i: ["info", TESTDATA / "ros2" / "replay_testing" / "cmd_vel_only.mcap"], testdata=True),
    case("demo-4", lambda i: _bc(i.demo_with("v-x.mcap", dataset=lambda d: d | {"format_version": "x"}))),
    case("demo-5", lambda i: _bc(i.demo_with("v-3.mcap", dataset=lambda d: d | {"format_version": "3"}))),
    case("demo-6", lambda i: _bc(i.demo_with("crc.mcap", dataset=lambda d: d | {"env_id": "Other-v0"}, crc=False))),
    case("demo-7", lambda i: _bc(i.demo_with("no-env.mcap", dataset=lambda d: {k: v for k, v in d.items() if k != "env_id"}))),
    case("demo-8 space-13", lambda i: _bc(i.demo_with("space.mcap", dataset=lambda d: d | {"observation_space": '{"type": "Bogus"}'}))),
    case("demo-9", lambda i: _bc(i.demo_with("dt.mcap", dataset=lambda d: d | {"dt_ns": "soon"}))),
    case("demo-10", lambda i: _bc(i.demo_with("user.mcap", dataset=lambda d: d | {"user_metadata": "{"}))),
    case("demo-11 demo-d2", lambda i: _bc(i.truncated("half.mcap"))),
    case("demo-13", lambda i: ["info", i.path("magic.mcap").write_bytes(b"\x89MCAP0\r\n" + b"\x07" * 40) and i.root / "magic.mcap"]),
    case("demo-14 demo-d23", lambda i: _bc(i.flipped_chunk("flip.mcap"))),
    case("demo-15", lambda i: _bc(i.demo_with("short-block.mcap", message=lambda k, data: data[:-4] if k == 1 else data))),
    case("demo-17", lambda i: _bc([DATASETS / "CartPole-v1.mcap", DATASETS / "Pendulum-v1.mcap"], "--out", i.root / "d17")),
    case("demo-18", lambda i: _bc([DATASETS / "CartPole-v1.mcap", i.demo_with("pend-as-cp.mcap", "Pendulum-v1.mcap", dataset=lambda d: d | {"env_id": "CartPole-v1"})])),
    case("demo-21", lambda i: _bc(i.episodes_file("empty.mcap", [], "CartPole-v1.mcap"))),
    case("demo-24", lambda i: _bc(i.demo_with("flags.mcap", dataset=lambda d: d | {"end_flags": "[1]"}))),
    case("demo-d1", lambda i: _bc(i.path("tiny.mcap").write_bytes(b"\x89MCAP0\r\n" + b"\0" * 10) and i.root / "tiny.mcap")),
    case("demo-d5", lambda i: _bc(i.flipped_summary("summary.mcap"))),
    case("demo-d14", lambda i: ["info", i.cut_at_record("cut-body.mcap", 20)]),
    case("demo-d3", lambda i: _bc(i.patched("no-summary.mcap", lambda d, s, c: d.__setitem__(slice(len(d) - 28, len(d) - 20), bytes(8))))),
    case("demo-d10", lambda i: _bc(i.patched("index-past.mcap", _index_field(16, struct.pack("<Q", 10**9))))),
    case("demo-d27", lambda i: ["info", i.demo_with("renumbered.mcap", episodes=lambda e: [{**e[0], "index": 5}, *e[1:]])]),
    case("demo-d28", lambda i: ["info", i.demo_with("twice.mcap", episodes=lambda e: [*e[:2], {**e[1], "index": 2}, *[{**x, "index": k + 3} for k, x in enumerate(e[2:])]])]),
    case("demo-d29", lambda i: ["info", i.demo_with("forged-steps.mcap", episodes=lambda e: [{**e[0], "length": 10**15}, *e[1:]])]),
    case("limit-1", lambda i: ["info", i.demo_with("huge-box.mcap", dataset=lambda d: d | {"observation_space": HUGE_BOX})]),
    case("limit-2", lambda i: ["--limit", "sample_size=5", "info", DATASETS / "CartPole-v1.mcap"]),
    case("limit-3", lambda i: ["--limit", "sample_elements=many", "info", DATASETS / "CartPole-v1.mcap"]),
    case("limit-5", lambda i: _convert(TURTLE, "--map", i.text("long-int.yaml", "rate_hz: 1" + "0" * 500 + "\n")), testdata=True),
    case("train-mem", lambda i: ["train", "bc", "--demos", i.demo_with("wide.mcap", dataset=lambda d: d | {"observation_space": WIDE_BOX}), "--hidden", "linear",
                                 "--epochs", "1", "--quiet", "--out", i.root / "wide-run"]),
    case("out-2", lambda i: ["record", "--env", "CartPole-v1", "--episodes", "1", "--quiet", "--out", "/dev/null"], expect="--out /dev/null: "),
    case("out-5", lambda i: ["record", "--env", "CartPole-v1", "--episodes", "1", "--quiet", "--out", _planted_link(i, "planted.mcap")]),
    case("out-6", lambda i: ["record", "--env", "CartPole-v1", "--episodes", "1", "--quiet", "--out", _left_partial(i, "held.mcap")]),
    case("out-12", lambda i: ["record", "--env", "CartPole-v1", "--episodes", "1", "--quiet", "--out", _linked_lock(i, "linked.mcap")]),
    case("out-7", lambda i: ["train", "ppo", "--env", "CartPole-v1", "--steps", "4096", "--quiet", "--out", i.interrupted_ppo("again")]),
    case("out-10", lambda i: ["eval", "policy", _weights_as_folder(i.policy_run("o10")), "--env", "CartPole-v1", "--episodes", "1"]),
    case("rec-1", lambda i: ["recover", DATASETS / "CartPole-v1.mcap"]),
    case("rec-2", lambda i: ["recover", _left_partial(i, "r2.mcap").with_name("r2.mcap.partial"), "--out", i.text("taken.mcap", "x")]),
    case("rec-3", lambda i: ["recover", _before_first_chunk(i, "early.mcap.partial")]),
    case("conv-nan", _npz_case("sb_npz", "nan.npz", obs=np.full((6, 4), np.nan, np.float32))),
    case("sb3-20", lambda i: _sb3(i.sb3_zip("deep.zip", members={"data": b"[" * 100_000 + b"]" * 100_000, "policy.pth": _pth()}))),
    case("demo-d18", lambda i: _bc(i.patched("brotli.mcap", lambda d, s, c: d.__setitem__(slice(c + 9 + 28 + 4, c + 9 + 28 + 8), b"brot")))),
    case("out-1", lambda i: ["record", "--env", "CartPole-v1", "--episodes", "1", "--out", i.root / "missing" / "x.mcap"]),
    # spaces (inside a demo file's metadata or a run's config)
    case("space-5", lambda i: _bc(i.demo_with("s5.mcap", dataset=lambda d: d | {"observation_space": '{"type": "Box"}'}))),
    case("space-6", lambda i: _bc(i.demo_with("s6.mcap", dataset=lambda d: d | {"observation_space": "[1, 2]"}))),
    case("space-7", lambda i: _bc(i.demo_with("s7.mcap", dataset=lambda d: d | {"observation_space": '{"type": "Box", "dtype": "float32", "shape": [-1], "low": 0, "high": 1}'}))),
    case("space-3", lambda i: _bc(i.demo_with("s3.mcap", dataset=lambda d: d | {"observation_space": json.dumps({"type": "Dict", "spaces": {"a/b": {"type": "Discrete", "n": 2}}})}))),
    case("space-9", lambda i: _bc(i.demo_with("s9.mcap", dataset=lambda d: d | {"observation_space": '{"type": "Box", "dtype": 5, "shape": [4], "low": 0, "high": 1}'}))),
    case("space-11", lambda i: _bc(i.demo_with("s11.mcap", dataset=lambda d: d | {"observation_space": '{"type": "Discrete", "n": 0}'}))),
    case("space-12", lambda i: _bc(i.demo_with("s12.mcap", dataset=lambda d: d | {"observation_space": '{"type": "Dict", "spaces": [1]}'}))),
    case("space-10", lambda i: _bc(i.demo_with("s10.mcap", dataset=lambda d: d | {"observation_space": '{"type": "Box", "dtype": "U8", "shape": [4], "low": 0, "high": 1}'}))),
    case("space-14", lambda i: ["eval", "policy", i.policy_run("cp-run"), "--env", "Pendulum-v1", "--episodes", "1"]),
    # training
    case("train-1", lambda i: _bc(DATASETS / "CartPole-v1.mcap", "--patience", "0", "--out", i.root / "t1"), expect="--patience must"),
    case("train-1", lambda i: ["train", "ppo", "--env", "CartPole-v1", "--n-envs", "0", "--out", i.root / "t1-ppo"], variant="ppo", expect="--n-envs must"),
    case("train-1", lambda i: ["train", "dagger", "--env", "CartPole-v1", "--expert", "scripted", "--epochs", "0", "--out", i.root / "t1-dagger"],
         variant="dagger", expect="--epochs must"),
    case("train-2", lambda i: _bc(DATASETS / "CartPole-v1.mcap", "--lr", "0", "--out", i.root / "t2"), expect="--lr must"),
    case("train-58", lambda i: _bc(DATASETS / "CartPole-v1.mcap", "--policy", "mixture", "--out", i.root / "t58"), expect="--policy must"),
    case("train-2", lambda i: ["train", "irl", "--env", "imitation/GridWorld8x8-v0", "--demos", DATASETS / "GridWorld8x8-v0.mcap", "--lr", "0",
                               "--out", i.root / "t2-irl"], variant="irl", expect="--lr must"),
    case("train-2", lambda i: ["train", "irl", "--method", "gcl", "--env", "CartPole-v1", "--demos", DATASETS / "CartPole-v1.mcap", "--lr", "0",
                               "--out", i.root / "t2-gcl"], variant="gcl", expect="--lr must"),
    case("train-1", lambda i: ["train", "irl", "--method", "gail", "--env", "CartPole-v1", "--demos", DATASETS / "CartPole-v1.mcap",
                               "--discriminator-steps", "0", "--out", i.root / "t1-gail"], variant="gail", expect="--discriminator-steps must"),
    case("train-2", lambda i: ["train", "irl", "--method", "airl", "--env", "CartPole-v1", "--demos", DATASETS / "CartPole-v1.mcap", "--lr", "0",
                               "--out", i.root / "t2-airl"], variant="airl", expect="--lr must"),
    case("irl-28", lambda i: ["train", "irl", "--method", "airl", "--env", "CartPole-v1", "--demos", DATASETS / "CartPole-v1.mcap",
                              "--gradient-penalty", "-1", "--out", i.root / "irl28"], expect="--gradient-penalty must"),
    case("irl-29", lambda i: ["train", "irl", "--method", "airl", "--env", "CartPole-v1", "--demos", DATASETS / "CartPole-v1.mcap",
                              "--gail-reward", "logit", "--out", i.root / "irl29"], expect="--gail-reward: chooses GAIL's reward, and --method airl"),
    case("irl-30", lambda i: ["train", "irl", "--method", "gcl", "--env", "CartPole-v1", "--demos", DATASETS / "CartPole-v1.mcap",
                              "--pool-rollouts", "4", "--out", i.root / "irl30"], expect="--pool-rollouts: sets the training of GAIL's and AIRL's discriminator, and --method gcl has none"),
    case("irl-31", lambda i: ["train", "irl", "--method", "airl", "--env", "CartPole-v1", "--demos", DATASETS / "CartPole-v1.mcap",
                              "--latest-share", "2", "--out", i.root / "irl31"], expect="--latest-share must be in [0, 1], got 2.0"),
    case("irl-32", lambda i: ["train", "irl", "--method", "gcl", "--env", "CartPole-v1", "--demos", DATASETS / "CartPole-v1.mcap",
                              "--warm-start", i.reward_run("irl32"), "--out", i.root / "irl32-out"], expect="--warm-start: starts GAIL's and AIRL's discriminator"),
    case("irl-33", lambda i: ["train", "irl", "--method", "airl", "--env", "CartPole-v1", "--demos", DATASETS / "CartPole-v1.mcap",
                              "--warm-start", i.reward_run("irl33"), "--out", i.root / "irl33-out"]),
    case("irl-34", lambda i: ["train", "irl", "--method", "gail", "--env", "CartPole-v1", "--demos", DATASETS / "CartPole-v1.mcap", "--warm-start",
                              i.reward_run("irl34", config=lambda c: c | {"irl": {"method": "gail"}, "env_id": "Acrobot-v1"}), "--out", i.root / "irl34-out"]),
    case("irl-35", lambda i: ["train", "irl", "--method", "gail", "--env", "CartPole-v1", "--demos", DATASETS / "CartPole-v1.mcap", "--warm-start",
                              i.reward_run("irl35", config=lambda c: c | {"irl": {"method": "gail"}}), "--out", i.root / "irl35-out"]),
    case("train-5", lambda i: _bc(DATASETS / "CartPole-v1.mcap", "--loss", "mse", "--out", i.root / "t5"), expect="--loss mse"),
    case("train-7", _checkpoint_mismatch(PREPARE_BC, "bc", {"epoch": 2}), expect="this BC run"),
    case("train-7", lambda i: ["train", "ppo", "--env", "CartPole-v1", "--steps", "4096", "--quiet", "--resume", "--out", i.interrupted_ppo("bad-ckpt")],
         variant="ppo", expect="this PPO run"),
    case("train-7", _checkpoint_mismatch(PREPARE_DAGGER, "dagger", {"round": 2}), variant="dagger", expect="this DAgger run"),
    case("train-7", _checkpoint_mismatch(PREPARE_IRL, "irl", {"iteration": 2}), variant="irl", expect="this tabular IRL run"),
    case("train-11", lambda i: ["train", "ppo", "--env", "CartPole-v1", "--steps", "10", "--out", i.root / "t11"], expect="--steps 10 is less"),
    case("train-11", lambda i: ["train", "irl", "--method", "gcl", "--env", "CartPole-v1", "--demos", DATASETS / "CartPole-v1.mcap", "--steps", "10",
                                "--out", i.root / "t11-gcl"], variant="gcl", expect="--steps 10 is less"),
    # policy gradient (train pg)
    case("pg-2", lambda i: ["train", "pg", "--env", "CartPole-v1", "--n-envs", "0", "--out", i.root / "pg2"], expect="--n-envs must"),
    case("pg-3", lambda i: ["train", "pg", "--env", "CartPole-v1", "--n-step", "3", "--out", i.root / "pg3"], expect="--n-step is for"),
    case("pg-4", lambda i: ["train", "pg", "--env", "CartPole-v1", "--steps", "10", "--out", i.root / "pg4"], expect="--steps 10 is less"),
    case("pg-5", lambda i: ["train", "pg", "--env", "CartPole-v1", "--estimator", "actor-critic", "--gae-lambda", "1.5", "--out", i.root / "pg5"],
         expect="--gae-lambda must"),
    case("pg-6", lambda i: ["train", "pg", "--env", "CartPole-v1", "--lr", "0", "--out", i.root / "pg6"], expect="--lr must"),
    case("pg-7", lambda i: ["train", "pg", "--env", "nan_envs:NaNReward-v0", "--steps", "4000", "--quiet", "--out", i.root / "pg7"],
         expect="non-finite reward"),
    case("train-13", lambda i: ["train", "ppo", "--env", "CartPole-v1", "--steps", "2048", "--quiet", "--out", i.root / "t13",
                                "--reward", i.reward_run("nan-reward", weights=_nan_weights)]),
    case("train-17", lambda i: ["train", "ppo", "--env", "CartPole-v1", "--quiet", "--resume", "--out", i.root / "never"]),
    case("train-18", lambda i: ["train", "ppo", "--env", "CartPole-v1", "--quiet", "--resume", "--out", i.folder("early.partial").parent / "early"]),
    case("train-19", lambda i: ["train", "ppo", "--env", "CartPole-v1", "--steps", "8192", "--quiet", "--resume", "--out", i.interrupted_ppo("other-steps")]),
    # A checkpoint of an earlier version, which did not record the run's settings: config.json holds them.
    case("train-20", _checkpoint_case("ckpt-config", **{"config.json": "{", "checkpoint__state.json": '{"history": [], "trainer": {}}'})),
    case("train-21", _checkpoint_case("ckpt-not-json", **{"checkpoint__state.json": "{"})),
    case("train-22", _checkpoint_case("ckpt-list", **{"checkpoint__state.json": "[]"})),
    case("train-23", _checkpoint_case("ckpt-rows", **{"checkpoint__state.json": '{"history": 5}'})),
    case("train-25", lambda i: ["demo", "--quick", "--quiet", "--out", i.text("plain-file", "x") / "run"]),
    case("train-26", lambda i: _bc(DATASETS / "CartPole-v1.mcap", "--device", "toaster", "--out", i.root / "t26"), expect="--device 'toaster': "),
    case("train-27", lambda i: _bc(DATASETS / "CartPole-v1.mcap", "--device", "cuda", "--out", i.root / "t27"), expect="--device cuda: "),
    case("train-28", lambda i: _bc(DATASETS / "CartPole-v1.mcap", "--validation", "1", "--out", i.root / "t28")),
    case("dagger-2", lambda i: ["train", "dagger", "--env", "CartPole-v1", "--expert", "scripted", "--rounds", "0", "--out", i.root / "d2"], expect="--rounds must"),
    case("dagger-2", lambda i: ["train", "dagger", "--env", "CartPole-v1", "--expert", "scripted", "--episodes-per-round", "0", "--out", i.root / "d2-episodes"],
         variant="episodes", expect="--episodes-per-round must"),
    case("dagger-3", lambda i: ["train", "dagger", "--env", "CartPole-v1", "--expert", "scripted", "--beta-decay", "2", "--out", i.root / "d3"], expect="--beta-decay must"),
    case("train-31", lambda i: _bc(DATASETS / "CartPole-v1.mcap", "--frame-stack", "0", "--out", i.root / "t31"), expect="--frame-stack must"),
    case("train-32", lambda i: _bc(DATASETS / "CartPole-v1.mcap", "--random-shift", "-1", "--out", i.root / "t32"), expect="--random-shift must"),
    case("train-33", lambda i: _bc(DATASETS / "CartPole-v1.mcap", "--frame-stack", "2", "--out", i.root / "t33"), expect="--frame-stack stacks"),
    case("train-34", lambda i: ["train", "dagger", "--env", "CartPole-v1", "--expert", "scripted", "--frame-stack", "2", "--out", i.root / "t34"],
         expect="--frame-stack stacks"),
    case("train-35", lambda i: _bc(i.episodes_file("t35.mcap", _cartpole_episodes(), "CartPole-v1.mcap", metadata={"pixels": {"size": [84]}}))),
    case("train-36", lambda i: _bc(i.episodes_file("t36.mcap", _cartpole_episodes(), "CartPole-v1.mcap",
                                                   metadata={"pixels": {"size": [84, 84], "grayscale": False, "frame_stack": 0}}))),
    case("train-37", lambda i: ["train", "bc", "--demos", _dict_demos(i), "--observation-keys", "a,c", "--epochs", "1", "--quiet", "--out", i.root / "t37"]),
    case("train-38", lambda i: ["train", "bc", "--demos", _multibinary_demos(i), "--epochs", "1", "--quiet", "--out", i.root / "t38"]),
    case("train-40", lambda i: ["train", "dagger", "--env", "CartPole-v1", "--expert", "scripted", "--pixels", "8x8", "--rounds", "1", "--episodes-per-round", "1",
                                "--epochs", "1", "--quiet", "--out", i.root / "t40"]),
    case("train-43", lambda i: ["train", "bc", "--demos", DATASETS / "Pendulum-v1.mcap", "--env", "Pendulum-v1", "--previous-action", "on", "--stream-memory", "64",
                                "--epochs", "1", "--quiet", "--out", i.root / "t43"], expect="--stream-memory streams"),
    case("train-45", lambda i: _bc(DATASETS / "CartPole-v1.mcap", "--threads", "0", "--out", i.root / "t45"), expect="--threads must"),
    case("train-50", lambda i: ["train", "ppo", "--env", "CartPole-v1", "--shaped", "--out", i.root / "t50"]),
    case("train-52", lambda i: _bc(DATASETS / "CartPole-v1.mcap", "--image-size", "40x40", "--out", i.root / "t52")),
    case("train-53", lambda i: ["train", "bc", "--demos", _camera_demos(i, 48, 64), "--crop", "0,0,60,64", "--quiet", "--out", i.root / "t53"]),
    case("train-54", lambda i: ["train", "bc", "--demos", _camera_demos(i, 480, 640), "--quiet", "--out", i.root / "t54"]),
    case("train-55", lambda i: ["train", "bc", "--demos", _camera_demos(i, 256, 256), "--batch-size", "100000", "--epoch-samples", "100000", "--quiet",
                                "--out", i.root / "t55"]),
    case("train-44", lambda i: _bc(DATASETS / "CartPole-v1.mcap", "--stream-memory", "0.001", "--batch-size", "256", "--out", i.root / "t44")),
    case("irl-1", lambda i: ["train", "irl", "--env", "imitation/GridWorld8x8-v0", "--demos", DATASETS / "GridWorld8x8-v0.mcap", "--discount", "0", "--out", i.root / "i1"],
         expect="--discount must"),
    case("irl-6", lambda i: ["train", "irl", "--env", "imitation/GridWorld8x8-v0", "--demos", DATASETS / "GridWorld8x8-v0.mcap", "--iterations", "0", "--out", i.root / "i6"],
         expect="--iterations must"),
    case("irl-11", _grid(_state_99)),
    case("irl-13", lambda i: ["train", "irl", "--method", "maxent", "--env", "imitation/GridWorld8x8Slippery-v0", "--demos", DATASETS / "GridWorld8x8Slippery-v0.mcap",
                              "--out", i.root / "i13"], expect="--method maxent"),
    case("irl-14", _grid(_too_long)),
    # apprenticeship learning
    case("app-1", lambda i: ["train", "irl", "--method", "apprenticeship", "--env", "imitation/GridWorld8x8-v0", "--demos", DATASETS / "GridWorld8x8-v0.mcap",
                             "--iterations", "0", "--out", i.root / "app1"], expect="--iterations must"),
    case("app-2", lambda i: ["train", "irl", "--method", "apprenticeship", "--env", "imitation/GridWorld8x8-v0", "--demos", DATASETS / "GridWorld8x8-v0.mcap",
                             "--tolerance", "1", "--out", i.root / "app2"], expect="--tolerance must"),
    case("app-3", lambda i: ["train", "irl", "--method", "apprenticeship", "--env", "FrozenLake-v1", "--demos", DATASETS / "CartPole-v1.mcap",
                             "--out", i.root / "app3"]),
    # gradient-free policy search
    case("search-2", lambda i: ["train", "cem", "--env", "CartPole-v1", "--population", "0", "--out", i.root / "s2"], expect="--population must"),
    case("search-2", lambda i: ["train", "hill-climb", "--env", "CartPole-v1", "--episodes-per-candidate", "0", "--out", i.root / "s2-hc"], variant="hill-climb",
         expect="--episodes-per-candidate must"),
    case("search-3", lambda i: ["train", "cmaes", "--env", "CartPole-v1", "--population", "1", "--out", i.root / "s3"], expect="--population must"),
    case("search-4", lambda i: ["train", "cem", "--env", "CartPole-v1", "--elite-fraction", "0", "--out", i.root / "s4"], expect="--elite-fraction must"),
    case("search-5", lambda i: ["train", "cem", "--env", "CartPole-v1", "--sigma", "0", "--out", i.root / "s5"], expect="--sigma must"),
    case("search-8", lambda i: ["train", "cem", "--env", "CartPole-v1", "--steps", "100", "--quiet", "--out", i.root / "s8"], expect="--steps 100 is less"),
    # run directories
    case("run-1", lambda i: ["eval", "policy", i.root / "no-run", "--env", "CartPole-v1"]),
    case("run-sb3", lambda i: ["eval", "policy", f"sb3:{TESTDATA / 'experts' / 'sb3_ppo_cartpole' / 'CartPole-v1.zip'}", "--env", "CartPole-v1"],
         testdata=True),
    case("run-2", lambda i: ["eval", "policy", i.folder("empty-run"), "--env", "CartPole-v1"]),
    case("run-3", lambda i: ["eval", "policy", _edit(i.policy_run("r3"), "config.json", b"{\xff"), "--env", "CartPole-v1"]),
    case("run-4", lambda i: ["eval", "policy", _edit(i.policy_run("r4"), "config.json", b"[1]"), "--env", "CartPole-v1"]),
    case("run-5", lambda i: ["eval", "policy", _edit(i.policy_run("r5"), "model.safetensors", b"\x80\x04garbage"), "--env", "CartPole-v1"]),
    case("run-6", lambda i: ["eval", "policy", i.reward_run("r6"), "--env", "CartPole-v1"]),
    case("run-24", lambda i: ["eval", "policy", i.policy_run("r24", config=lambda c: c | {"policy": c["policy"] | {"kind": "mixture"}}), "--env", "CartPole-v1"]),
    case("run-7", lambda i: ["eval", "policy", i.policy_run("r7", weights=lambda t: {k: (v[:, :3] if v.dim() == 2 and v.shape[1] == 4 else v) for k, v in t.items()}), "--env", "CartPole-v1"]),
    case("run-8", lambda i: ["eval", "policy", i.policy_run("r8", config=lambda c: c | {"policy": c["policy"] | {"hidden_sizes": [4096, 4096]}}), "--env", "CartPole-v1"]),
    case("run-9", lambda i: ["eval", "policy", i.policy_run("r9", config=lambda c: c | {"policy": c["policy"] | {"observation_space": {"type": "Bogus"}}}), "--env", "CartPole-v1"]),
    case("run-10", lambda i: ["train", "ppo", "--env", "CartPole-v1", "--out", i.root / "r10-ppo",
                              "--reward", i.reward_run("r10", config=lambda c: c | {"reward": c["reward"] | {"action_space": {"type": "Box"}}})]),
    case("run-11", lambda i: ["train", "ppo", "--env", "CartPole-v1", "--out", i.root / "r11-ppo", "--reward", i.policy_run("r11")]),
    case("run-12", lambda i: ["train", "ppo", "--env", "CartPole-v1", "--out", i.root / "r12-ppo",
                              "--reward", i.reward_run("r12", weights=lambda t: {k: v.T.contiguous() if v.dim() == 2 else v for k, v in t.items()})]),
    case("run-22", lambda i: ["train", "ppo", "--env", "CartPole-v1", "--out", i.root / "r22-ppo", "--reward", i.reward_run("r22"), "--shaped"]),
    case("run-14", lambda i: ["train", "bc", "--demos", _multidiscrete_demos(i), "--epochs", "1", "--out", i.root / "r14"]),
    # stable-baselines3 zips
    case("sb3-1", lambda i: _sb3(i.text("not.zip", "not a zip"))),
    case("sb3-2", lambda i: _sb3(i.sb3_zip("no-pth.zip", members={"data": b"{}"}))),
    case("sb3-3", lambda i: _sb3(i.sb3_zip("pickled.zip", weights={"w": _Opaque()}))),
    case("sb3-4", lambda i: _sb3(i.sb3_zip("list.zip", weights=[torch.zeros(1)]))),
    case("sb3-5", lambda i: _sb3(i.sb3_zip("data-not-json.zip", members={"data": b"{", "policy.pth": _pth()}))),
    case("sb3-6", lambda i: _sb3(i.sb3_zip("data-list.zip", members={"data": b"[]", "policy.pth": _pth()}))),
    case("sb3-8", lambda i: _sb3(i.sb3_zip("image.zip", observation=gym.spaces.Box(0, 255, (8, 8, 3), np.uint8)))),
    case("sb3-9", lambda i: _sb3(i.sb3_zip("no-space.zip", data={"observation_space": {}}))),
    case("sb3-10", lambda i: _sb3(i.sb3_zip("unreadable-space.zip", data={"action_space": {":type:": "<class 'gymnasium.spaces.discrete.Discrete'>"}}))),
    case("sb3-11", lambda i: _sb3(i.sb3_zip("multi.zip", action=gym.spaces.MultiDiscrete([2, 2])))),
    case("sb3-12", lambda i: _sb3(i.sb3_zip("cnn.zip", weights=sb3_weights(4, 2, pi=[8], vf=[8]) | {"features_extractor.cnn.0.weight": torch.zeros(1)}))),
    case("sb3-13", lambda i: _sb3(i.sb3_zip("shared.zip", weights={"mlp_extractor.shared_net.0.weight": torch.zeros(8, 4), "mlp_extractor.shared_net.0.bias": torch.zeros(8),
                                                                     "mlp_extractor.policy_net.0.weight": torch.zeros(8, 8), "mlp_extractor.policy_net.0.bias": torch.zeros(8)}))),
    case("sb3-14", lambda i: _sb3(i.sb3_zip("sizes.zip", weights={"mlp_extractor.policy_net.0.weight": torch.zeros(8, 4), "mlp_extractor.policy_net.0.bias": torch.zeros(8),
                                                                    "mlp_extractor.value_net.0.weight": torch.zeros(16, 4), "mlp_extractor.value_net.0.bias": torch.zeros(16)}))),
    case("sb3-15", lambda i: _sb3(i.sb3_zip("layers.zip", weights={"mlp_extractor.policy_net.1.weight": torch.zeros(8, 4), "mlp_extractor.policy_net.1.bias": torch.zeros(8)}))),
    case("sb3-16", lambda i: _sb3(i.sb3_zip("kwargs.zip", data={"policy_kwargs": {":type:": "<class 'dict'>", ":serialized:": "bm90IGEgcGlja2xl"}}))),
    case("sb3-18", lambda i: _sb3(i.sb3_zip("elu.zip", data={"policy_kwargs": {":type:": "<class 'dict'>", ":serialized:": _pickled_elu()}}))),
    case("sb3-19", lambda i: _sb3(i.sb3_zip("misfit.zip", action=gym.spaces.Discrete(3)))),
    case("sb3-21", lambda i: _sb3(i.sb3_zip("recurrent.zip", data={"policy_class": _policy_class("sb3_contrib.ppo_recurrent.policies", "RecurrentActorCriticPolicy")}))),
    case("sb3-22", lambda i: _sb3(i.sb3_zip("class.zip", data={"policy_class": {":type:": "<class 'abc.ABCMeta'>", ":serialized:": "!!", "__module__": "x"}}))),
    case("sb3-23", lambda i: _sb3(i.sb3_zip("sac-cnn.zip", weights=_layers("actor.latent_pi.", [4, 8]), data={"policy_class": _policy_class("stable_baselines3.sac.policies", "CnnPolicy")}))),
    case("sb3-25", lambda i: _sb3(i.sb3_zip("sac-discrete.zip", weights=_layers("actor.latent_pi.", [4, 8]), data={"policy_class": _policy_class("stable_baselines3.sac.policies", "SACPolicy")}))),
    case("sb3-26", lambda i: _sb3(i.sb3_zip("dqn-inputs.zip", weights=_layers("q_net.q_net.", [3, 8, 2])))),
    case("sb3-27", lambda i: _sb3(i.sb3_zip("dqn-outputs.zip", weights=_layers("q_net.q_net.", [4, 8, 3])))),
    case("sb3-28", lambda i: _sb3(i.sb3_zip("dqn-layers.zip", weights={"q_net.q_net.1.weight": torch.zeros(2, 4), "q_net.q_net.1.bias": torch.zeros(2)}))),
    case("sb3-29", lambda i: _sb3(i.sb3_zip("sac-clip.zip", weights=_layers("actor.latent_pi.", [4, 8]) | _layers("actor.mu.", [8, 1]), observation=gym.spaces.Box(-1, 1, (4,), np.float32),
                                          action=gym.spaces.Box(-1, 1, (1,), np.float32), data={"policy_kwargs": {"clip_mean": -1}}))),
    case("sb3-30", lambda i: _sb3(i.sb3_zip("sac-mean.zip", weights=_layers("actor.latent_pi.", [4, 8]) | _layers("actor.mu.", [8, 8, 1]), action=gym.spaces.Box(-1, 1, (1,), np.float32)))),
    case("sb3-31", lambda i: _sb3(i.sb3_zip("dqn-bias.zip", weights={"q_net.q_net.0.weight": torch.zeros(2, 4)}))),
    case("sb3-32", lambda i: _sb3(i.sb3_zip("dqn-chain.zip", weights=_layers("q_net.q_net.", [4, 8]) | {"q_net.q_net.2.weight": torch.zeros(2, 5), "q_net.q_net.2.bias": torch.zeros(2)}))),
    # convert
    case("conv-1", lambda i: _convert(i.root / "absent.npz")),
    case("conv-2", lambda i: _convert(i.text("notes.txt", "hello"))),
    case("conv-hdf5", lambda i: _convert(shutil.copy(REPO / "tests" / "fixtures" / "formats" / "robomimic-layout.hdf5", i.root))),
    case("conv-3", lambda i: _convert(i.folder("plain-folder"))),
    case("conv-4", lambda i: _convert((i.folder("half-lerobot/meta") and i.root / "half-lerobot"))),
    case("conv-6", lambda i: _convert(i.sb_npz("c6.npz"), "--from", "hdf5")),
    case("conv-7", lambda i: _convert(TURTLE), testdata=True),
    case("conv-8", lambda i: _convert(i.sb_npz("c8.npz"), "--map", i.turtle_map("c8.yaml"))),
    case("conv-9", lambda i: _convert(i.sb_npz("c9.npz"), "--inspect", out=None)),
    case("conv-12", lambda i: ["convert", i.sb_npz("c12.npz"), "--out", i.folder("out-folder")]),
    case("conv-15", _npz_case("sb_npz", "c15.npz", "--env", "CartPole-v1", actions=np.zeros((6, 2), np.int64))),
    case("conv-16", _npz_case("sb_npz", "c16.npz", "--env", "CartPole-v1", actions=np.full((6, 1), 0.5))),
    case("conv-17", _npz_case("sb_npz", "c17.npz", "--env", "CartPole-v1", actions=np.full((6, 1), 5))),
    case("conv-18", _npz_case("sb_npz", "c18.npz", "--env", "CartPole-v1", obs=np.zeros((6, 3), np.float32))),
    case("npz-1", lambda i: _convert(i.path("broken.npz").write_bytes(b"PK\x03\x04" + b"\0" * 60) and i.root / "broken.npz")),
    case("npz-2", lambda i: _convert(_npy(i), "--from", "npz")),
    case("npz-4", _npy_claiming_more),
    case("npz-5", lambda i: _convert(i.npz("other.npz", a=np.zeros(3), b=np.ones(3)))),
    case("npz-6", _npz_case("sb_npz", "n6.npz", obs=np.array(["a"] * 6))),
    case("npz-7", _npz_case("sb_npz", "n7.npz", rewards=np.ones(5))),
    case("npz-8", _npz_case("imitation_npz", "n8.npz", indices=np.array([3.0]))),
    case("npz-9", _npz_case("imitation_npz", "n9.npz", indices=np.array([1, 2]))),
    case("npz-10", _npz_case("imitation_npz", "n10.npz", indices=np.array([9]))),
    case("npz-11", _npz_case("imitation_npz", "n11.npz", rews=np.ones(4))),
    case("ends-1", _npz_case("imitation_npz", "long.npz", "--env", "CartPole-v1", obs=np.zeros((504, 4), np.float32), acts=np.zeros(502, np.int64),
                             indices=np.array([1]), terminal=np.array([True, True]), rews=np.ones(502))),
    case("ends-2", _array_case("no-env", "--no-env")),
    case("ends-3", _array_case("ts-no-env", "--no-env", ends="terminal_state")),
    case("ends-4", _pendulum_terminal_state),
    case("ends-5", _array_case("ts-not-env", ends="terminal_state")),  # ARRAY's rows are not MountainCar's steps
    case("map-1", lambda i: _convert(i.npz("a1.npz", demos=ARRAY), "--layout", i.root / "absent.yaml"), variant="layout"),
    case("map-3", _array_case("deep", layout="[" * 5000 + "]" * 5000), variant="layout"),
    case("arr-3", _array_case("list", layout="- observation\n- action\n")),
    case("arr-4", _array_case("stride", stride=2)),
    case("arr-5", _array_case("rows", rows="after")),
    case("arr-5", _array_case("padding", padding="zeros"), variant="padding"),
    case("arr-6", _array_case("both", action=[1])),
    case("arr-7", _array_case("next", rows="next_state", final_state="row")),
    case("arr-8", _two_arrays),
    case("arr-9", _array_case("flat", data=ARRAY[0])),
    case("arr-10", _cut_npy),
    case("arr-11", _array_case("col7", observation=[0, 7])),
    case("arr-12", _array_case("names", columns=["position", "velocity"])),
    case("arr-13", _array_case("empty", data=np.full((2, 4, 3), np.nan))),
    case("arr-14", _array_case("half", data=np.where(ARRAY == 2, 0.5, ARRAY))),
    case("arr-15", _array_case("hole", data=np.concatenate([ARRAY[:, :2], np.full((2, 1, 3), np.nan), ARRAY[:, 2:]], axis=1))),
    case("arr-16", lambda i: _convert(_npy(i), "--env", "MountainCar-v0")),
    case("arr-17", lambda i: _convert(i.sb_npz("a17.npz"), "--from", "npz", "--layout", i.text("a17.yaml", yaml.safe_dump(LAYOUT)))),
    # LeRobot
    case("lerobot-1", lambda i: _convert(i.folder("not-lerobot"), "--from", "lerobot", out=None) + ["--out", i.root / "l1.mcap"]),
    case("lerobot-2", lambda i: _convert(_replace(i.lerobot("l2"), "meta/info.json", "{"), "--from", "lerobot", out=None) + ["--out", i.root / "l2.mcap"], testdata=True),
    case("lerobot-4", _lerobot_case("l4", info=lambda d: d | {"features": 5}), testdata=True),
    case("lerobot-5", _lerobot_case("l5", info=lambda d: d | {"fps": -1}), testdata=True),
    case("lerobot-6", _lerobot_case("l6", info=lambda d: d | {"features": {k: v for k, v in d["features"].items() if not k.startswith("observation.")}}), testdata=True),
    case("lerobot-7", _lerobot_case("l7", info=lambda d: d | {"features": {k: v for k, v in d["features"].items() if k != "action"}}), testdata=True),
    case("lerobot-8", _lerobot_case("l8", info=lambda d: d | {"codebase_version": "v9.9"}), testdata=True),
    case("lerobot-3", _lerobot_v30("v30-no-rows", _v30_without_rows), testdata=True),
    case("lerobot-20", _lerobot_v30("v30-no-data", lambda root: shutil.rmtree(root / "data")), testdata=True),
    case("lerobot-21", _lerobot_v30("v30-cut", lambda root: _cut_in_half(_v30_data_file(root))), testdata=True),
    case("lerobot-11", _lerobot_v30("v30-no-listing", lambda root: shutil.rmtree(root / "meta" / "episodes")), testdata=True, variant="v3.0"),
    case("lerobot-11", lambda i: _convert(_remove(i.lerobot("l11"), "meta/episodes.jsonl"), "--from", "lerobot", out=None) + ["--out", i.root / "l11.mcap"], testdata=True),
    case("lerobot-12", _lerobot_case("l12", episodes='{"tasks": []}\n'), testdata=True),
    case("lerobot-13", _lerobot_case("l13", drop=("data/chunk-000/episode_000001.parquet",)), testdata=True),
    case("lerobot-14", _lerobot_case("l14", episodes='{"episode_index": 0, "length": 3}\n'), testdata=True),
    case("lerobot-16", _lerobot_case("l16", info=lambda d: d | {"features": d["features"] | {"action": d["features"]["action"] | {"shape": [7]}}}), testdata=True),
    case("lerobot-19", _lerobot_case("l19", episodes=""), testdata=True),
    case("lerobot-29", _lerobot_case("l29", info=lambda d: d | {"data_path": "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"}),
         testdata=True),
    # bags
    case("bag-1", lambda i: _convert(i.sb_npz("b1.npz"), "--from", "ros1", "--inspect", out=None)),
    case("bag-4", _sqlite_without_metadata),
    case("bag-5", lambda i: _convert(i.folder("empty-bag"), "--from", "ros2", "--inspect", out=None)),
    case("bag-6", _rosbag2_metadata("bag6", "[unclosed")),
    case("bag-7", _rosbag2_metadata("bag7", "rosbag2_bagfile_information: {storage_identifier: bogus}")),
    case("bag-8", _rosbag2_metadata("bag8", "rosbag2_bagfile_information: {storage_identifier: mcap, relative_file_paths: [gone.mcap]}")),
    case("bag-9", lambda i: _convert(i.text("fake.bag", "#ROSBAG V2.0\ngarbage"), "--from", "ros1", "--inspect", out=None)),
    case("bag-10", _damaged_mcap_bag, testdata=True),
    # A ROS 1 bag carries its own definitions and never uses the distro's: the name is checked all the same.
    case("bag-11", lambda i: _convert(TURTLE, "--map", i.turtle_map("b11.yaml"), "--ros-distro", "hunble"), testdata=True, expect="'hunble'"),
    # maps (against PlotJuggler's turtlesim bag)
    case("map-1", lambda i: _convert(TURTLE, "--map", i.root / "absent.yaml"), testdata=True),
    case("map-2", lambda i: _convert(TURTLE, "--map", i.text("bad.yaml", "a: [")), testdata=True),
    case("map-3", lambda i: _convert(TURTLE, "--map", i.text("deep.yaml", "[" * 5000 + "]" * 5000)), testdata=True),
    case("map-4", lambda i: _convert(TURTLE, "--map", i.text("list.yaml", "- 1\n")), testdata=True),
    case("map-5", _map_case("m5.yaml", bogus=1), testdata=True),
    case("map-6", _map_case("m6.yaml", rate_hz=0), testdata=True),
    case("map-7", _map_case("m7.yaml", time="wall"), testdata=True),
    case("map-8", _map_case("m8.yaml", align="cubic"), testdata=True),
    case("map-9", _map_case("m9.yaml", env_id=5), testdata=True),
    case("map-11", _map_case("m11.yaml", observation={"topic": "/turtle1/pose", "fields": ["x"]}), testdata=True),
    case("map-12", _map_case("m12.yaml", reward={"topic": "/turtle1/pose", "fields": ["x", "y"]}), testdata=True),
    case("map-13", _map_case("m13.yaml", observation=[5]), testdata=True),
    case("map-14", _entry_case("m14.yaml", rate=3), testdata=True),
    case("map-15", _map_case("m15.yaml", observation=[{"fields": ["x"]}]), testdata=True),
    case("map-16", _entry_case("m16.yaml", fields=[]), testdata=True),
    case("map-17", _entry_case("m17.yaml", fields=["a..b"]), testdata=True),
    case("map-18", _entry_case("m18.yaml", align="cubic"), testdata=True),
    case("map-19", _entry_case("m19.yaml", default="zero"), testdata=True),
    case("map-20", _entry_case("m20.yaml", default=0.0, max_age=-1), testdata=True),
    case("map-21", _entry_case("m21.yaml", max_age=1), testdata=True),
    case("map-22", _map_case("m22.yaml", episodes={"split": "moon"}), testdata=True),
    case("map-23", _map_case("m23.yaml", episodes={"split": "file", "seconds": 1}), testdata=True),
    case("map-24", _map_case("m24.yaml", episodes={"split": "gap"}), testdata=True),
    case("map-25", _map_case("m25.yaml", episodes={"split": "topic"}), testdata=True),
    case("map-27", _entry_case("m27.yaml", size=[4, 4]), testdata=True),
    case("map-28", _map_case("m28.yaml", action=[{"topic": "/turtle1/cmd_vel", "image": "cam"}]), testdata=True),
    case("map-29", _map_case("m29.yaml", observation=[{"topic": "/turtle1/pose", "image": "state"}]), testdata=True),
    case("map-30", _map_case("m30.yaml", observation=[{"topic": "/turtle1/pose", "image": "cam", "default": 0}]), testdata=True),
    case("map-31", _map_case("m31.yaml", observation=[{"topic": "/turtle1/pose", "image": "cam", "align": "interpolate"}]), testdata=True),
    case("map-32", _map_case("m32.yaml", observation=[{"topic": "/turtle1/pose", "image": "cam", "size": [480]}]), testdata=True),
    case("map-33", _map_case("m33.yaml", observation=[{"topic": "/turtle1/pose", "image": "cam"}, {"topic": "/turtle1/cmd_vel", "image": "cam"}]), testdata=True),
    # ROS conversion
    case("ros-4", lambda i: _convert(TESTDATA / "ros2" / "rosbag2_tests" / "bag_with_topics_and_service_events", "--map", i.text("r4.yaml", yaml.safe_dump(
        {"rate_hz": 10, "observation": [{"topic": "/test_service1/_service_event", "fields": ["x"]}], "action": [{"topic": "/test_service1/_service_event", "fields": ["x"]}]})),
        out=None) + ["--out", i.root / "r4.mcap"], testdata=True),
    case("ros-5", lambda i: _convert(TESTDATA / "ros2" / "rosbag2_tests" / "talker", "--map", i.text("r5.yaml", yaml.safe_dump(
        {"rate_hz": 10, "observation": [{"topic": "/rosout", "fields": ["level"]}], "action": [{"topic": "/parameter_events", "fields": ["stamp.sec"]}]})),
        out=None) + ["--out", i.root / "r5.mcap"], testdata=True),
    case("ros-7", lambda i: _convert(TESTDATA / "ros1" / "plotjuggler_rosbag2_sqlite", "--from", "ros2", "--map", i.text("r7.yaml", yaml.safe_dump(
        {"rate_hz": 25, "observation": [{"topic": "/imu", "fields": ["orientation.x"]}], "action": [{"topic": "/battery", "fields": ["cell_temperature"]}]}))),
        testdata=True),
    case("ros-8", lambda i: _convert(TURTLE, "--map", i.turtle_map("r8.yaml", action=[{"topic": "/turtle1/cmd_vel", "fields": ["linear.x", "angular.z"], "default": [0.0, 0.0, 0.0]}])), testdata=True),
    case("ros-10", _map_case("r10.yaml", time="header"), testdata=True),
    case("ros-15", _map_case("r15.yaml", observation=[{"topic": "/turtle1/pose", "image": "cam"}]), testdata=True),
    # export
    case("export-2", lambda i: ["export", i.episodes_file("nothing.mcap", [], "CartPole-v1.mcap"), "--to", "lerobot", i.root / "nothing-lerobot"]),
    case("export-3", lambda i: ["export", DATASETS / "CartPole-v1.mcap", "--to", "lerobot", i.text("full/keep.txt", "x").parent]),
    case("export-4", lambda i: ["export", DATASETS / "CartPole-v1.mcap", "--to", "foxglove", i.folder("fox-folder")]),
    case("export-5", lambda i: ["export", DATASETS / "CartPole-v1.mcap", "--to", "foxglove", DATASETS / "CartPole-v1.mcap"]),
    # evaluation and the demo
    case("eval-1", lambda i: ["eval", "reward", i.reward_run("no-demos", demos=False), "--env", "CartPole-v1", "--retrain-steps", "0", "--quiet"]),
    case("eval-2", lambda i: ["eval", "reward", i.root / "any", "--env", "CartPole-v1", "--seeds", "0"], expect="--seeds must"),
    case("eval-3", lambda i: ["eval", "reward", i.root / "any", "--env", "CartPole-v1", "--retrain-steps", "-1"], expect="--retrain-steps must"),
    case("eval-4", lambda i: ["eval", "reward", i.root / "any", "--env", "CartPole-v1", "--jobs", "0"], expect="--jobs must"),
    case("eval-5", lambda i: ["eval", "policy", i.policy_run("e5"), "--env", "CartPole-v1", "--episodes", "1", "--video", i.root / "v.avi"]),
    case("eval-6", lambda i: ["eval", "policy", i.policy_run("e6"), "--env", "CartPole-v1", "--episodes", "1", "--video", i.root / "no-folder" / "v.gif"]),
    case("demo-cmd-1", lambda i: ["demo", "--datasets", i.folder("no-datasets"), "--out", i.root / "demo-out", "--quick"]),
]
CASES = {entry_id: c for c in CASE_LIST for entry_id in c.ids}


class _Opaque:
    """Pickled by torch.save as a class reference: a weights-only load refuses it."""


def _policy_class(module: str, name: str) -> dict:
    """The `policy_class` entry SB3 writes: a pickle of the class reference (read by its opcodes,
    never run) and the class's readable `__module__`."""
    payload = b"\x80\x02c" + f"{module}\n{name}\n".encode() + b"q\x00."
    return {":type:": "<class 'abc.ABCMeta'>", ":serialized:": base64.b64encode(payload).decode(), "__module__": module}


def _layers(prefix: str, sizes: list[int]) -> dict:
    """An MLP's Linear layers as SB3 names them: PREFIX{0,2,4,...}.weight/bias for these widths."""
    layers = {}
    for index, (inputs, outputs) in enumerate(zip(sizes[:-1], sizes[1:])):
        layers[f"{prefix}{2 * index}.weight"] = torch.zeros(outputs, inputs)
        layers[f"{prefix}{2 * index}.bias"] = torch.zeros(outputs)
    return layers


def _pth() -> bytes:
    buffer = io.BytesIO()
    torch.save({"action_net.weight": torch.zeros(2, 4)}, buffer)
    return buffer.getvalue()


def _pickled_elu() -> str:
    import base64
    import pickle

    return base64.b64encode(pickle.dumps({"activation_fn": torch.nn.ELU}, protocol=4)).decode()


def _npy(i: Inputs) -> Path:
    path = i.path("array.npz")
    with open(path, "wb") as stream:
        np.save(stream, np.zeros(3))
    return path


def _edit(run: Path, name: str, content: bytes) -> Path:
    (run / name).write_bytes(content)
    return run


def _replace(root: Path, relative: str, text: str) -> Path:
    (root / relative).write_text(text)
    return root


def _remove(root: Path, relative: str) -> Path:
    (root / relative).unlink()
    return root


HUGE_BOX = json.dumps({"type": "Box", "dtype": "float32", "shape": [2**26], "low": "-inf", "high": "inf"})
WIDE_BOX = json.dumps({"type": "Box", "dtype": "float32", "shape": [2**23], "low": "-inf", "high": "inf"})


def _planted_link(i: Inputs, name: str) -> Path:
    """`name`, whose partial file is a symlink to a file the writer must not touch."""
    (i.root / f"{name}.partial").symlink_to(i.text(f"{name}.victim", "keep me"))
    return i.root / name


def _linked_lock(i: Inputs, name: str) -> Path:
    """`name`, whose lock file is a hard link to a file the writer must not touch."""
    os.link(i.text(f"{name}.victim", "keep me"), i.root / f".{name}.lock")
    return i.root / name


def _left_partial(i: Inputs, name: str) -> Path:
    """`name`, beside a partial file holding finished episodes (a bundled demo file's)."""
    shutil.copy(DATASETS / "CartPole-v1.mcap", i.root / f"{name}.partial")
    return i.root / name


def _before_first_chunk(i: Inputs, name: str) -> Path:
    """A bundled demo file cut where its first chunk starts: the dataset metadata, no episode."""
    data = (DATASETS / "CartPole-v1.mcap").read_bytes()
    at = 8  # magic
    while data[at] != 0x06:  # chunk opcode
        at += 9 + struct.unpack_from("<Q", data, at + 1)[0]
    path = i.path(name)
    path.write_bytes(data[:at])
    return path


def _weights_as_folder(run: Path) -> Path:
    (run / "model.safetensors").unlink()
    (run / "model.safetensors").mkdir()
    return run


def _dict_demos(i: Inputs) -> Path:
    from imitation.data.mcap.writer import write_episodes
    from imitation.data.types import Episode

    space = gym.spaces.Dict({"a": gym.spaces.Box(-1, 1, (2,), np.float32), "b": gym.spaces.Box(-1, 1, (1,), np.float32)})
    episode = Episode(observations={"a": np.zeros((4, 2), np.float32), "b": np.zeros((4, 1), np.float32)}, actions=np.zeros((3, 1), np.float32), rewards=np.zeros(3))
    return write_episodes(i.path("dict-obs.mcap"), [episode, episode], env_id="", observation_space=space, action_space=gym.spaces.Box(-1, 1, (1,), np.float32))


def _multidiscrete_demos(i: Inputs) -> Path:
    """MultiDiscrete observations (not in a Dict), which no policy reads."""
    from imitation.data.mcap.writer import write_episodes
    from imitation.data.types import Episode

    episode = Episode(observations=np.zeros((4, 2), np.int64), actions=np.zeros((3, 1), np.float32), rewards=np.zeros(3))
    return write_episodes(i.path("multidiscrete-obs.mcap"), [episode, episode], env_id="", observation_space=gym.spaces.MultiDiscrete([3, 3]),
                          action_space=gym.spaces.Box(-1, 1, (1,), np.float32))


def _camera_demos(i: Inputs, height: int, width: int) -> Path:
    """Two short episodes of H×W camera frames (PNG) beside a state, written by the demo writer."""
    from imitation.data.mcap.writer import write_episodes
    from imitation.data.types import Episode

    path = i.path(f"camera-{height}x{width}.mcap")
    if path.exists():
        return path
    space = gym.spaces.Dict({"pixels": gym.spaces.Box(0, 255, (height, width, 3), np.uint8), "state": gym.spaces.Box(-1, 1, (2,), np.float32)})
    frames = np.broadcast_to(np.arange(width, dtype=np.uint8)[None, :, None], (4, height, width, 3))
    episode = Episode(observations={"pixels": np.ascontiguousarray(frames), "state": np.zeros((4, 2), np.float32)},
                      actions=np.zeros((3, 1), np.float32), rewards=np.zeros(3))
    return write_episodes(path, [episode, episode], env_id="", observation_space=space, action_space=gym.spaces.Box(-1, 1, (1,), np.float32),
                          image_codec="png")


def _multibinary_demos(i: Inputs) -> Path:
    """Dict observations with a MultiBinary leaf, which no policy reads."""
    from imitation.data.mcap.writer import write_episodes
    from imitation.data.types import Episode

    space = gym.spaces.Dict({"a": gym.spaces.Box(-1, 1, (2,), np.float32), "keys": gym.spaces.MultiBinary(3)})
    episode = Episode(observations={"a": np.zeros((4, 2), np.float32), "keys": np.zeros((4, 3), np.int8)}, actions=np.zeros((3, 1), np.float32), rewards=np.zeros(3))
    return write_episodes(i.path("multibinary-obs.mcap"), [episode, episode], env_id="", observation_space=space, action_space=gym.spaces.Box(-1, 1, (1,), np.float32))


# ------------------------------------------------------------------------------------------------
# The run


@pytest.fixture(scope="module")
def results(tmp_path_factory) -> dict[str, object]:
    inputs = Inputs(tmp_path_factory.mktemp("errors"))
    run_cli_many([PREPARE_BC + [inputs.root / "bc-done"], PREPARE_DAGGER + [inputs.root / "dagger-done"], PREPARE_IRL + [inputs.root / "irl-done"]])
    runnable = [c for c in CASE_LIST if not (c.testdata and not TESTDATA.is_dir())]
    if torch.cuda.is_available():
        runnable = [c for c in runnable if "train-27" not in c.ids]
    argvs = [[str(a) for a in c.argv(inputs)] for c in runnable]
    outcomes = run_cli_many(argvs, env={"PYTHONPATH": f"{REPO}:{REPO / 'tests'}"}, timeout=900)
    return {c.name: (c, outcome) for c, outcome in zip(runnable, outcomes)}


@pytest.mark.parametrize("name", [c.name for c in CASE_LIST])
def test_each_message_through_the_cli(results, name: str) -> None:
    if name not in results:
        pytest.skip("needs ../shared/testdata (or runs only without CUDA)")
    case_, outcome = results[name]
    lines = [line for line in outcome.stderr.splitlines() if line.strip()]
    assert outcome.returncode == 1, (outcome.returncode, outcome.stderr[-2000:])
    assert len(lines) == 1 and lines[0].startswith("error: "), outcome.stderr[-2000:]
    message = lines[0].removeprefix("error: ")
    for entry_id in case_.ids:
        template = ENTRIES[entry_id].template
        assert pattern_regex(template).search(message), f"{entry_id}: {message!r} does not match {template!r}"
    assert case_.expect in message, f"{name}: {message!r} does not say {case_.expect!r}"
