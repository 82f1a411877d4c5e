"""Load a stable-baselines3 policy zip as an `ActorCritic`, without unpickling anything.

Why no pickle: SB3's own `load` unpickles parts of the zip (cloudpickled spaces, schedules, the
policy class), and unpickling runs whatever code the file names, so a downloaded expert could run
anything. Here the zip is read as data only, and stable-baselines3 is not needed:

- `policy.pth` with `torch.load(weights_only=True)`, which rebuilds tensors and plain containers
  and refuses every other global;
- `data` as JSON. SB3 writes each value JSON cannot hold as {":type:", ":serialized:" (base64
  cloudpickle)} plus the object's attributes as JSON or `str()`; the spaces are read from those
  readable attributes (`shape`/`_shape`, `dtype`, `low`, `high`, `n`, `start`). The activation
  function is only inside `policy_kwargs`' pickle: its opcodes are listed with
  `pickletools.genops`, which disassembles without executing, to find the class it names;
- the architecture from the names and shapes of the weights.

Supported: SB3 PPO and A2C `MlpPolicy` (ActorCriticPolicy with the flattening feature extractor),
Box or Discrete observations, Discrete or Box (diagonal Gaussian) actions, Tanh (SB3's default)
or ReLU activations, actor and critic networks of the same sizes or one shared network.

Not supported, refused with an `ImitationError`: CNN and MultiInput policies (a feature extractor
with weights), image observations (SB3 scales them by 1/255), gSDE, actor and critic networks of
different sizes, other algorithms' networks (DQN, SAC, TD3). VecNormalize statistics are not in the
zip but in a separate pickle (`vecnormalize.pkl`) and are not loaded: an expert trained with
VecNormalize sees unnormalised observations here and will act badly.
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
from pickletools import genops  # disassembles a pickle without running it
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from imitation.errors import ImitationError
from imitation.limits import LIMITS, check_zip_member, over_limit
from imitation.policies import ACTIVATIONS, ActorCritic, action_logits_size, make_policy

# SB3 module names → ours. The trunks are nn.Sequential(Linear, activation, ...) in both, so
# hidden-layer indices carry over unchanged.
HEADS = {
    "action_net.weight": "action_head.weight",
    "action_net.bias": "action_head.bias",
    "value_net.weight": "value_head.weight",
    "value_net.bias": "value_head.bias",
    "log_std": "log_std",
}
HIDDEN_LAYER = re.compile(r"mlp_extractor\.(policy_net|value_net|shared_net)\.(\d+)\.(weight|bias)")
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


def load_sb3_policy(path: str | os.PathLike) -> ActorCritic:
    """The policy in an SB3 PPO/A2C zip, as an ActorCritic on the CPU in eval mode."""
    file = os.fspath(path)
    weights, data = _read_zip(file)
    if data.get("use_sde"):
        raise ImitationError(f"{file}: the policy uses gSDE (state-dependent exploration), which is not supported")
    observation_space = _space(file, data, "observation_space")
    action_space = _space(file, data, "action_space")
    if (
        isinstance(observation_space, gym.spaces.Box)
        and observation_space.dtype == np.uint8
        and len(observation_space.shape) == 3
    ):
        raise ImitationError(f"{file}: image observations are not supported (SB3 scales them by 1/255 inside the policy)")
    hidden_sizes, shared, state = _rename_weights(file, weights)
    head = state.get("action_head.weight")
    if head is not None and head.dim() == 2 and head.shape[0] != action_logits_size(action_space):
        # Checked before the network is built: a forged space could otherwise ask for a huge head.
        details = f"its action head has {head.shape[0]} outputs, the action space needs {action_logits_size(action_space)}"
        raise ImitationError(f"{file}: policy.pth does not fit the zip's spaces ({details})")
    policy = make_policy(
        observation_space, action_space, hidden_sizes=hidden_sizes, activation=_activation(file, data), shared_trunk=shared
    )
    # The action bounds are buffers of ours that SB3 keeps in the action space, read above.
    state.update({name: tensor for name, tensor in policy.state_dict().items() if name in ("action_low", "action_high")})
    try:
        policy.load_state_dict(state)
    except RuntimeError as error:
        details = "; ".join(line.strip() for line in str(error).splitlines()[1:]) or str(error)
        raise ImitationError(f"{file}: policy.pth does not fit the zip's spaces ({details})") from None
    return policy.eval()


def _read_zip(file: str) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
    """The `policy.pth` state dict and the `data` JSON of an SB3 zip."""
    try:
        with zipfile.ZipFile(file) as archive:
            names = set(archive.namelist())
            for member in ("policy.pth", "data"):
                if member not in names:
                    raise ImitationError(f"{file}: no {member} in the zip, so not a stable-baselines3 PPO/A2C model")
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


def _space(file: str, data: dict[str, Any], key: str) -> gym.Space:
    """A Box or Discrete space from the readable attributes SB3 writes beside the pickle."""
    entry = data.get(key)
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


def _rename_weights(file: str, weights: dict[str, torch.Tensor]) -> tuple[list[int], bool, dict[str, torch.Tensor]]:
    """Hidden sizes, whether the trunk is shared, and the weights under our module names."""
    layers: dict[str, dict[int, dict[str, torch.Tensor]]] = {"policy_net": {}, "value_net": {}, "shared_net": {}}
    state: dict[str, torch.Tensor] = {}
    for name, tensor in weights.items():
        if name in HEADS:
            state[HEADS[name]] = tensor
        elif match := HIDDEN_LAYER.fullmatch(name):
            layers[match[1]].setdefault(int(match[2]), {})[match[3]] = tensor
        else:
            raise ImitationError(
                f"{file}: policy.pth holds {name!r}, which an SB3 PPO/A2C MlpPolicy does not have "
                "(CNN, MultiInput and custom feature extractors are not supported)"
            )
    sizes = {net: _hidden_sizes(file, net, found) for net, found in layers.items()}
    if sizes["shared_net"] and (sizes["policy_net"] or sizes["value_net"]):
        raise ImitationError(f"{file}: a shared network followed by separate actor/critic layers is not supported")
    if sizes["shared_net"]:
        trunks: dict[str, tuple[str, ...]] = {"shared_net": ("actor_trunk", "critic_trunk")}
    elif sizes["policy_net"] != sizes["value_net"]:
        raise ImitationError(
            f"{file}: actor hidden sizes {sizes['policy_net']} differ from critic hidden sizes {sizes['value_net']}, which "
            "is not supported"
        )
    else:
        trunks = {"policy_net": ("actor_trunk",), "value_net": ("critic_trunk",)}
    for net, ours in trunks.items():
        for index, params in layers[net].items():
            for param, tensor in params.items():
                state.update({f"{trunk}.{index}.{param}": tensor for trunk in ours})
    return sizes["shared_net"] or sizes["policy_net"], bool(sizes["shared_net"]), state


def _hidden_sizes(file: str, net: str, found: dict[int, dict[str, torch.Tensor]]) -> list[int]:
    """Output sizes of an MLP's Linear layers, which sit at indices 0, 2, 4, ... (activations between)."""
    indices = sorted(found)
    linear = all(set(found[i]) == {"weight", "bias"} and found[i]["weight"].dim() == 2 for i in indices)
    if indices != list(range(0, 2 * len(indices), 2)) or not linear:
        raise ImitationError(
            f"{file}: mlp_extractor.{net} is not Linear layers alternating with activations (layers {indices})"
        )
    return [int(found[i]["weight"].shape[0]) for i in indices]


def _activation(file: str, data: dict[str, Any]) -> str:
    """Our name of the activation class `policy_kwargs` names; Tanh, SB3 PPO/A2C's default, when none."""
    kwargs = data.get("policy_kwargs")
    # Plain-JSON policy_kwargs hold no classes, so no activation_fn: SB3 used its default.
    if not isinstance(kwargs, dict) or ":serialized:" not in kwargs:
        return "tanh"
    try:
        imported = set(_pickle_globals(base64.b64decode(kwargs[":serialized:"])))
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
        return "tanh"
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


def _pickle_globals(payload: bytes) -> Iterator[tuple[str, str]]:
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
