"""No file can make the package run code: the source holds no unpickling call (an AST scan keeps
it so), and crafted files whose pickles would create a marker file are refused with one line
while the marker never appears."""

from __future__ import annotations

import base64
import builtins
import io
import json
import pickle
import zipfile
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from sb3_zips import sb3_weights, space_entry
from source_scan import scan_files, scan_source
from support import REPO, run_cli_many
from test_cli import assert_one_line_error, last_json

from imitation.policies import make_policy, policy_tensors
from imitation.runs import RunWriter

# ------------------------------------------------------------------------------------------------
# The source scan


def package_sources() -> list[Path]:
    return sorted((REPO / "imitation").rglob("*.py")) + [REPO / "cli.py"]


def test_the_package_has_no_code_execution_from_data() -> None:
    sources = package_sources()
    assert len(sources) > 30 and REPO / "imitation" / "experts" / "sb3.py" in sources
    findings = scan_files(sources)
    assert not findings, "\n".join(map(str, findings))


@pytest.mark.parametrize(
    "snippet",
    [
        "import pickle",
        "import pickle as p",
        "from pickle import loads",
        "import cPickle",
        "import _pickle",
        "import dill",
        "from joblib import load",
        "import cloudpickle",
        "import shelve",
        "import torch\ntorch.load(f)",
        "import torch\ntorch.load(f, weights_only=False)",
        "import torch\ntorch.load(f, weights_only=flag)",
        "from torch import load\nload(f)",
        "from torch import load as tl\ntl(f, map_location='cpu')",
        "import torch.serialization\ntorch.serialization.load(f)",
        "import numpy as np\nnp.load(f, allow_pickle=True)",
        "import numpy\nnumpy.load(f, allow_pickle=x)",
        "from numpy import load\nload(f, allow_pickle=True)",
        "import yaml\nyaml.load(text)",
        "import yaml\nyaml.load(text, Loader=yaml.Loader)",
        "import yaml\nyaml.load(text, yaml.FullLoader)",
        "import yaml\nyaml.unsafe_load(text)",
        "import yaml\nyaml.full_load(text)",
        "import pandas as pd\npd.read_pickle(f)",
        "eval(text)",
        "exec(code)",
        "compile(text, 'x', 'exec')",
        "__import__(name)",
    ],
)
def test_the_scan_flags_each_forbidden_pattern(snippet: str) -> None:
    assert scan_source(snippet), snippet


@pytest.mark.parametrize(
    "snippet",
    [
        "from pickletools import genops",
        "import torch\ntorch.load(f, weights_only=True, map_location='cpu')",
        "import numpy as np\nnp.load(f)",
        "import numpy as np\nnp.load(f, allow_pickle=False)",
        "import yaml\nyaml.safe_load(text)",
        "import yaml\nyaml.load(text, Loader=yaml.SafeLoader)",
        "import yaml\nyaml.load(text, Loader=yaml.CSafeLoader)",
        "policy.eval()",
        "model.compile()",
        "json.loads(text)",
    ],
)
def test_the_scan_passes_safe_calls(snippet: str) -> None:
    assert scan_source(snippet) == [], snippet


# ------------------------------------------------------------------------------------------------
# Crafted files


class MarkerPayload:
    """Unpickling this object calls open(marker, "w"): the file appears iff the pickle ran."""

    def __init__(self, marker: Path) -> None:
        self.marker = str(marker)

    def __reduce__(self):
        return (builtins.open, (self.marker, "w"))


def payload(marker: Path) -> bytes:
    return pickle.dumps(MarkerPayload(marker), protocol=4)


def test_the_payload_is_live(tmp_path: Path) -> None:
    """Control: unpickling the payload does create the marker, so its absence below means the
    pickle was never run."""
    marker = tmp_path / "ran"
    pickle.loads(payload(marker)).close()
    assert marker.exists()


def torch_saved_payload(marker: Path) -> bytes:
    buffer = io.BytesIO()
    torch.save({"action_net.weight": MarkerPayload(marker)}, buffer)
    return buffer.getvalue()


CARTPOLE = (gym.spaces.Box(-np.inf, np.inf, (4,), np.float32), gym.spaces.Discrete(2))


def sb3_zip(path: Path, marker: Path, *, policy_pth: bytes | None = None, policy_kwargs_payload: bool = False) -> Path:
    """An SB3 PPO zip for CartPole whose every opaque `:serialized:` field is the payload."""
    if policy_pth is None:
        buffer = io.BytesIO()
        torch.save(sb3_weights(4, 2, pi=[8], vf=[8]), buffer)
        policy_pth = buffer.getvalue()
    evil = payload(marker)
    data = {
        "observation_space": space_entry(CARTPOLE[0], base64.b64encode(evil).decode()),
        "action_space": space_entry(CARTPOLE[1], base64.b64encode(evil).decode()),
        "learning_rate": {":type:": "<class 'function'>", ":serialized:": base64.b64encode(evil).decode()},
        "policy_kwargs": {":type:": "<class 'dict'>", ":serialized:": base64.b64encode(evil).decode()} if policy_kwargs_payload else {},
        "use_sde": False,
    }
    with zipfile.ZipFile(path, "w") as archive:
        archive.writestr("data", json.dumps(data))
        archive.writestr("policy.pth", policy_pth)
        archive.writestr("_stable_baselines3_version", "2.3.0")
    return path


def run_dir(folder: Path) -> Path:
    """A small, valid BC-like run directory with a CartPole policy."""
    policy = make_policy(*CARTPOLE, hidden_sizes=[8])
    with RunWriter(folder, config={"kind": "bc", "env_id": "CartPole-v1", "policy": policy.config.to_json()}, tensorboard=False) as run:
        run.save_weights(policy_tensors(policy))
        run.finish({})
    return folder


def evil_npz(path: Path, marker: Path) -> Path:
    rows = 5
    np.savez(path, obs=np.zeros((rows, 4), np.float32), actions=np.zeros((rows, 1), np.int64), rewards=np.ones(rows),
             episode_starts=np.eye(1, rows, dtype=bool)[0], episode_returns=np.array([MarkerPayload(marker)], dtype=object))
    return path


SB3_CASES = {
    "bare pickle as policy.pth": "policy.pth is not a plain PyTorch state dict",
    "torch.save of an object as policy.pth": "policy.pth is not a plain PyTorch state dict",
    "policy_kwargs' pickle names builtins.open": "policy_kwargs' pickle refers to _io.open",
}


@pytest.fixture(scope="module")
def crafted(tmp_path_factory) -> dict:
    """Every crafted file, each with its own marker, run through the CLI in one batch."""
    root = tmp_path_factory.mktemp("crafted")
    cases: dict[str, tuple[list, Path]] = {}
    for name in SB3_CASES:
        folder = root / name.replace(" ", "-").replace("'", "")
        folder.mkdir()
        marker = folder / "ran"
        if name.startswith("bare"):
            path = sb3_zip(folder / "evil.zip", marker, policy_pth=payload(marker))
        elif name.startswith("torch.save"):
            path = sb3_zip(folder / "evil.zip", marker, policy_pth=torch_saved_payload(marker))
        else:
            path = sb3_zip(folder / "evil.zip", marker, policy_kwargs_payload=True)
        cases[name] = (["record", "--env", "CartPole-v1", "--expert", f"sb3:{path}", "--episodes", "1", "--out", folder / "demos.mcap"], marker)
    opaque = root / "opaque"
    opaque.mkdir()
    path = sb3_zip(opaque / "opaque.zip", opaque / "ran")
    cases["opaque fields"] = (["record", "--env", "CartPole-v1", "--expert", f"sb3:{path}", "--episodes", "1", "--out", opaque / "d.mcap", "--json"], opaque / "ran")
    cases["valid run"] = (["eval", "policy", run_dir(root / "valid-run"), "--env", "CartPole-v1", "--episodes", "1", "--json"], root / "none")
    for kind in ("bare pickle", "torch.save"):
        folder = root / kind.replace(" ", "-")
        run = run_dir(folder / "run")
        marker = folder / "ran"
        (run / "model.safetensors").write_bytes(payload(marker) if kind == "bare pickle" else torch_saved_payload(marker))
        cases[f"weights: {kind}: eval"] = (["eval", "policy", run, "--env", "CartPole-v1", "--episodes", "1"], marker)
        cases[f"weights: {kind}: record"] = (["record", "--env", "CartPole-v1", "--expert", run, "--episodes", "1", "--out", folder / "x.mcap"], marker)
    npz = root / "npz"
    npz.mkdir()
    cases["npz"] = (["convert", evil_npz(npz / "evil.npz", npz / "ran"), "--out", npz / "demos.mcap"], npz / "ran")
    outcomes = run_cli_many([argv for argv, _ in cases.values()])
    return {name: (outcome, argv, marker) for (name, (argv, marker)), outcome in zip(cases.items(), outcomes)}


@pytest.mark.parametrize("case", list(SB3_CASES))
def test_a_crafted_sb3_zip_is_refused_and_never_runs(crafted: dict, case: str) -> None:
    result, argv, marker = crafted[case]
    zip_path = str(argv[4]).removeprefix("sb3:")
    assert_one_line_error(result, zip_path, SB3_CASES[case])
    assert "weights_only" not in result.stderr, "no advice to load the file unsafely"
    assert not marker.exists(), "the pickle ran"
    out = Path(argv[-1])
    assert not out.exists() and not out.with_name(out.name + ".partial").exists()


def test_pickles_in_fields_that_are_never_opened_do_not_run(crafted: dict) -> None:
    """The spaces' and schedules' pickles are ignored: the zip loads from its readable fields."""
    result, _, marker = crafted["opaque fields"]
    assert last_json(result)["episodes"] == 1
    assert not marker.exists(), "the pickle ran"


def test_the_valid_run_directory_loads(crafted: dict) -> None:
    """Control for the next test: those runs only fail because of their weights file."""
    assert last_json(crafted["valid run"][0])["episodes"] == 1


@pytest.mark.parametrize("kind", ["bare pickle", "torch.save"])
@pytest.mark.parametrize("command", ["eval", "record"])
def test_a_pickle_in_place_of_safetensors_weights_is_refused_and_never_runs(crafted: dict, kind: str, command: str) -> None:
    result, argv, marker = crafted[f"weights: {kind}: {command}"]
    run = Path(argv[2] if command == "eval" else argv[4])
    assert_one_line_error(result, str(run / "model.safetensors"), "unreadable safetensors file")
    assert not marker.exists(), "the pickle ran"


def test_the_npz_payload_is_live(tmp_path: Path) -> None:
    """Control: numpy would unpickle the crafted npz's object array if asked to, and the payload would run."""
    marker = tmp_path / "ran"
    with np.load(evil_npz(tmp_path / "evil.npz", marker), allow_pickle=True) as archive:
        archive["episode_returns"][0].close()
    assert marker.exists()


def test_an_npz_with_an_object_array_is_refused_and_never_runs(crafted: dict) -> None:
    result, argv, marker = crafted["npz"]
    assert_one_line_error(result, str(argv[1]), "array 'episode_returns' holds Python objects; it is not read")
    assert not marker.exists(), "the pickle ran"
    out = Path(argv[-1])
    assert not out.exists() and not out.with_name(out.name + ".partial").exists()
