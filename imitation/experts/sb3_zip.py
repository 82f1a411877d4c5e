"""A stable-baselines3 zip read as data: its weights, its readable settings and spaces, and
which algorithm wrote it, without unpickling anything.

Why no pickle: SB3's own `load` unpickles parts of the zip (cloudpickled spaces, schedules, the
policy class), and unpickling runs whatever code the file names, so a downloaded expert could run
anything. Here the zip is read as data only, and stable-baselines3 is not needed:

- `policy.pth` with `torch.load(weights_only=True)`, which rebuilds tensors and plain containers
  and refuses every other global;
- `data` as JSON. SB3 writes each value JSON cannot hold as {":type:", ":serialized:" (base64
  cloudpickle)} plus the object's attributes as JSON or `str()`; the spaces are read from those
  readable attributes (`shape`/`_shape`, `dtype`, `low`, `high`, `n`, `start`);
- the classes a pickle refers to (the policy class, which names the algorithm; the activation
  function in `policy_kwargs`) from its opcodes, listed with `pickletools.genops`, which
  disassembles without executing.
"""

from __future__ import annotations

import base64
import io
import json
import math
import os
import re
import warnings
import zipfile
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pickletools import genops  # disassembles a pickle without running it
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from imitation.errors import ImitationError
from imitation.inputs import check_input
from imitation.limits import LIMITS, check_zip_member, over_limit
from imitation.mlp import ACTIVATIONS

SPACE_TYPE = re.compile(r"<class '(?:gym|gymnasium)\.spaces\.\w+\.(\w+)'>")
ACTIVATION_MODULE = "torch.nn.modules.activation"
PLAIN_BUILTINS = {
    "dict",
    "list",
    "tuple",
    "set",
    "frozenset",
    "int",
    "float",
    "bool",
    "str",
    "bytes",
    "complex",
    "slice",
    "range",
}
STRING_OPCODES = {"STRING", "BINSTRING", "SHORT_BINSTRING", "UNICODE", "BINUNICODE", "SHORT_BINUNICODE", "BINUNICODE8"}
# The module of the policy class names the algorithm (PPO and A2C share ActorCriticPolicy; DDPG
# shares TD3's policy).
ALGORITHMS = {
    "stable_baselines3.common.policies": "PPO/A2C",
    "stable_baselines3.ppo.policies": "PPO/A2C",
    "stable_baselines3.a2c.policies": "PPO/A2C",
    "stable_baselines3.sac.policies": "SAC",
    "stable_baselines3.td3.policies": "TD3",
    "stable_baselines3.ddpg.policies": "TD3",
    "stable_baselines3.dqn.policies": "DQN",
    "sb3_contrib.tqc.policies": "TQC",
    "sb3_contrib.qrdqn.policies": "QR-DQN",
}
# Without a readable policy class (older zips), the weights' names tell: the first prefix found
# (SAC's actor has a latent_pi trunk before its mu head; TD3's is all mu).
WEIGHT_PREFIXES = {
    "mlp_extractor.": "PPO/A2C",
    "action_net.": "PPO/A2C",
    "actor.latent_pi.": "SAC",
    "actor.mu.": "TD3",
    "q_net.": "DQN",
    "quantile_net.": "QR-DQN",
}
# SB3's default activation per algorithm: the off-policy ones use ReLU.
DEFAULT_ACTIVATIONS = {"PPO/A2C": "tanh", "SAC": "relu", "TD3": "relu", "TQC": "relu", "DQN": "relu", "QR-DQN": "relu"}


@dataclass
class SB3Zip:
    """What an SB3 zip holds that an expert needs: the policy's weights, the `data` settings, the
    algorithm and the policy class's name (e.g. "SACPolicy", "CnnPolicy")."""

    file: str
    weights: dict[str, torch.Tensor]
    data: dict[str, Any]
    algorithm: str
    policy_class: str

    @property
    def where(self) -> str:
        """How messages name the zip: its path and the algorithm it holds."""
        return f"{self.file} ({self.algorithm})"


def read_sb3_zip(path: str | os.PathLike) -> SB3Zip:
    """An SB3 zip's weights and settings, and the algorithm that wrote it; refused in one line
    when it is not an SB3 zip, its members are unreadable, or the algorithm is not one of
    `ALGORITHMS`."""
    file = os.fspath(path)
    weights, data = _read_members(file)
    module, name = _policy_class(file, data)
    algorithm = ALGORITHMS.get(module) if module else None
    if algorithm is None and module is None:
        found = (
            algorithm for prefix, algorithm in WEIGHT_PREFIXES.items() if any(name.startswith(prefix) for name in weights)
        )
        algorithm = next(found, None)
    if algorithm is None:
        what = f"policy class {module}.{name}" if module else "weights of no known policy"
        raise ImitationError(
            f"{file}: a stable-baselines3 zip of an algorithm not supported ({what}); "
            f"supported: {', '.join(sorted(set(ALGORITHMS.values())))}"
        )
    return SB3Zip(file=file, weights=weights, data=data, algorithm=algorithm, policy_class=name or "MlpPolicy")


def _policy_class(file: str, data: dict[str, Any]) -> tuple[str | None, str | None]:
    """(module, class name) of the policy class: the module from its readable `__module__`, the
    name from the opcodes of its pickle (never run); (None, None) when the zip has neither."""
    entry = data.get("policy_class")
    if not isinstance(entry, dict):
        return None, None
    module = entry.get("__module__") if isinstance(entry.get("__module__"), str) else None
    name = None
    serialized = entry.get(":serialized:")
    if isinstance(serialized, str):
        try:
            named = [found for found in pickle_globals(base64.b64decode(serialized)) if module is None or found[0] == module]
        except (ValueError, TypeError) as error:
            raise ImitationError(f"{file}: its policy_class is not a readable pickle ({error})") from None
        if named:
            module, name = named[0]
    return module, name


def _read_members(file: str) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
    """The `policy.pth` state dict and the `data` JSON of an SB3 zip."""
    try:
        check_input(file)
        with zipfile.ZipFile(file) as archive:
            names = set(archive.namelist())
            for member in ("policy.pth", "data"):
                if member not in names:
                    raise ImitationError(f"{file}: no {member} in the zip, so not a stable-baselines3 model")
                check_zip_member(file, archive.getinfo(member))
            weights_bytes, data_bytes = archive.read("policy.pth"), archive.read("data")
    except (
        zipfile.BadZipFile,
        zlib.error,
        OSError,
        NotImplementedError,
        EOFError,
        ValueError,
        RuntimeError,
    ) as error:  # RuntimeError: "encrypted"
        raise ImitationError(f"{file}: cannot read as a stable-baselines3 zip ({str(error)[:200]})") from None
    try:
        with warnings.catch_warnings():  # torch warns on stderr about pickle protocols; one line only
            warnings.simplefilter("ignore")
            weights = torch.load(io.BytesIO(weights_bytes), weights_only=True, map_location="cpu")
    except Exception as error:  # noqa: BLE001 - any failure of a stranger's file is one line
        # weights_only refuses anything but tensors and plain containers: an unpickling error here
        # may also mean the file tried to import code.
        raise ImitationError(
            f"{file}: policy.pth is not a plain PyTorch state dict ({_refusal(error)}); nothing in it was run"
        ) from None
    if not isinstance(weights, dict) or not all(isinstance(v, torch.Tensor) for v in weights.values()):
        raise ImitationError(f"{file}: policy.pth holds a {type(weights).__name__}, not a state dict of tensors")
    try:
        data = json.loads(data_bytes)
    except ValueError as error:
        raise ImitationError(f"{file}: its data member is not JSON ({str(error)[:200]})") from None
    except RecursionError:
        raise ImitationError(f"{file}: its data member is JSON nested too deep to be an SB3 model's") from None
    if not isinstance(data, dict):
        raise ImitationError(f"{file}: its data member is JSON but not an object")
    return weights, data


def _refusal(error: Exception) -> str:
    """What torch's weights-only unpickler objected to, without its advice to retry unsafely."""
    text = " ".join(str(error).split())
    found = re.search(r"WeightsUnpickler error: (.*?)(?: Please use| Check the documentation|$)", text)
    reason = found[1] if found else text
    return reason.rstrip(". ")[:200] or type(error).__name__


def read_space(model: SB3Zip, key: str) -> gym.Space:
    """A Box or Discrete space from the readable attributes SB3 writes beside the pickle."""
    file, entry = model.where, model.data.get(key)
    match = SPACE_TYPE.fullmatch(entry[":type:"]) if isinstance(entry, dict) and isinstance(entry.get(":type:"), str) else None
    if match is None:
        raise ImitationError(f"{file}: data has no readable {key} (expected a gym/gymnasium space entry)")
    assert isinstance(entry, dict)  # match is only found in a dict entry
    kind = match[1]
    try:
        if kind == "Discrete":
            # Old gym wrote n as an int; gymnasium's n and start are numpy ints, written as str().
            n, start = int(_short_number(entry["n"])), int(_short_number(entry.get("start", 0)))
            if n > LIMITS.sample_elements:
                raise over_limit(f"{file}: {key} Discrete(n): n", n, "sample_elements")
            if n < 1:
                raise ValueError(f"Discrete n must be at least 1, got {n}")
            return gym.spaces.Discrete(n, start=start)
        if kind == "Box":
            shape = tuple(int(n) for n in (entry["shape"] if "shape" in entry else entry["_shape"]))
            if len(shape) > 32 or any(n < 0 for n in shape):
                raise ValueError(f"shape {shape} is not a list of at most 32 sizes ≥ 0")
            if math.prod(shape) > LIMITS.sample_elements:
                raise over_limit(f"{file}: {key} Box shape {shape}: numbers per sample", math.prod(shape), "sample_elements")
            dtype = np.dtype(entry["dtype"])
            low, high = (_parse_array(entry[bound], shape, dtype) for bound in ("low", "high"))
            return gym.spaces.Box(low=low, high=high, shape=shape, dtype=dtype)
    except (KeyError, TypeError, ValueError, OverflowError) as error:
        raise ImitationError(
            f"{file}: cannot read {key} ({kind}) from its readable fields, and its pickle is not opened: {error}"
        ) from None
    raise ImitationError(f"{file}: {key} is a {kind}; only Box and Discrete spaces are supported")


def _short_number(value: Any) -> Any:
    """`value`, refused when it is a string too long to be a number of a real space (Python's
    int() of a 5000-digit string is slow and refused anyway)."""
    if isinstance(value, str) and len(value) > 40:
        raise ValueError(f"{value[:40]}... is not a number a space holds")
    return value


def _parse_array(text: str, shape: tuple[int, ...], dtype: np.dtype) -> np.ndarray:
    """An array from its numpy `str()`, e.g. '[-4.8 -inf]'. numpy elides long arrays with '...',
    which loses values: refused rather than guessed."""
    if not isinstance(text, str):
        raise TypeError(f"bounds must be numpy's text of an array, got {type(text).__name__}")
    values = np.array(text.replace("[", " ").replace("]", " ").split()).astype(dtype)
    if values.size != int(np.prod(shape)):
        raise ValueError(f"bounds for shape {shape} (got {values.size} values from {text[:40]!r})")
    return values.reshape(shape)


def read_activation(model: SB3Zip) -> str:
    """Our name of the activation class `policy_kwargs` names; the algorithm's default when none
    (Tanh for PPO/A2C, ReLU for the off-policy algorithms)."""
    file, kwargs, default = model.where, model.data.get("policy_kwargs"), DEFAULT_ACTIVATIONS[model.algorithm]
    # Plain-JSON policy_kwargs hold no classes, so no activation_fn: SB3 used its default.
    if not isinstance(kwargs, dict) or ":serialized:" not in kwargs:
        return default
    try:
        imported = set(pickle_globals(base64.b64decode(kwargs[":serialized:"])))
    except (ValueError, TypeError) as error:
        raise ImitationError(f"{file}: policy_kwargs is not a readable pickle ({error})") from None
    foreign = sorted(f"{module}.{name}" for module, name in imported if not _plausible_setting(module, name))
    if foreign:
        raise ImitationError(
            f"{file}: policy_kwargs' pickle refers to {', '.join(foreign)}, which no SB3 policy setting is; "
            "refused (the pickle was not run)"
        )
    named = sorted(name for module, name in imported if module == ACTIVATION_MODULE)
    if not named:
        return default
    ours = {cls.__name__: key for key, cls in ACTIVATIONS.items()}
    if len(named) > 1 or named[0] not in ours:
        raise ImitationError(f"{file}: activation {', '.join(named)} is not supported (only {', '.join(sorted(ours))})")
    return ours[named[0]]


def _plausible_setting(module: str, name: str) -> bool:
    """Whether a global named in policy_kwargs' pickle is something SB3 settings hold: torch
    classes (activations, optimisers), SB3's own classes, numpy values, plain containers. The
    pickle is never run either way; naming anything else (os.system, builtins.open, ...) marks the
    zip as crafted, and it is refused rather than silently half-read."""
    top = module.split(".")[0]
    if top in ("torch", "stable_baselines3", "sb3_contrib", "numpy"):
        return True
    if module == "collections":
        return name in ("OrderedDict", "defaultdict")
    return module == "builtins" and name in PLAIN_BUILTINS


def pickle_globals(payload: bytes) -> Iterator[tuple[str, str]]:
    """(module, name) of each class or function the pickle would import, read from its opcodes
    without executing any. GLOBAL carries both names; STACK_GLOBAL takes them from the stack,
    where the two ops before it pushed them as strings, directly or from the memo. Only those
    pushes are tracked: any other push is recorded as None, which is all STACK_GLOBAL needs."""
    memo: dict[int, Any] = {}
    pushed: list[Any] = []
    arg: Any  # its type depends on the opcode: str for GLOBAL and the string pushes, int for the memo's
    for opcode, arg, _ in genops(payload):
        if opcode.name == "GLOBAL":
            module, name = arg.split(" ", 1)
            yield module, name
        elif opcode.name == "STACK_GLOBAL" and len(pushed) >= 2 and all(isinstance(s, str) for s in pushed[-2:]):
            yield pushed[-2], pushed[-1]
        if opcode.name == "MEMOIZE":
            memo[len(memo)] = pushed[-1] if pushed else None
        elif opcode.name in ("PUT", "BINPUT", "LONG_BINPUT"):
            memo[arg] = pushed[-1] if pushed else None
        elif opcode.name in ("GET", "BINGET", "LONG_BINGET"):
            pushed.append(memo.get(arg))
        elif opcode.name in STRING_OPCODES:
            pushed.append(arg)
        elif opcode.stack_after:
            pushed.append(None)
