"""YAML that cannot expand beyond a bound: maps and rosbag2 metadata come from strangers.

PyYAML's safe loader builds shared references for aliases, so an alias bomb (each level nine
aliases of the one before) is small in memory, but anything that walks the result (checking a
map, printing it in an error) walks every expansion: ×9 per level. `load_yaml` counts the nodes
of the document with every alias expanded, before anything is constructed, and refuses one
above `LIMITS.yaml_nodes`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from imitation.errors import ImitationError
from imitation.inputs import open_input
from imitation.limits import LIMITS, over_limit

MAX_INTEGER_DIGITS = 400


class _BoundedLoader(yaml.SafeLoader):
    def compose_document(self) -> yaml.Node | None:
        node = super().compose_document()
        if node is not None:
            expanded = _expanded_nodes(node)
            if expanded > LIMITS.yaml_nodes:
                raise over_limit("YAML nodes with aliases expanded", expanded, "yaml_nodes")
        return node

    def construct_yaml_int(self, node: yaml.ScalarNode) -> int:
        # Python refuses int() of more than 4300 digits with a ValueError; no real value has 400.
        if len(node.value) > MAX_INTEGER_DIGITS:
            raise ImitationError(
                f"line {node.start_mark.line + 1}: an integer of {len(node.value)} digits, more than any real value has"
            )
        return super().construct_yaml_int(node)


_BoundedLoader.add_constructor("tag:yaml.org,2002:int", _BoundedLoader.construct_yaml_int)


def _expanded_nodes(root: yaml.Node) -> int:
    """Nodes of the tree that the document's graph unfolds to (an alias counts its target's
    whole subtree again); linear in the graph's size, whatever the expansion."""
    counted: dict[int, int] = {}
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    while stack:
        node, children_done = stack.pop()
        if id(node) in counted:
            continue
        children = _children(node)
        if children_done or not children:
            counted[id(node)] = 1 + sum(counted.get(id(child), 0) for child in children)
            continue
        stack.append((node, True))
        stack.extend((child, False) for child in children if id(child) not in counted)
    return counted[id(root)]


def _children(node: yaml.Node) -> list[yaml.Node]:
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    if isinstance(node, yaml.MappingNode):
        return [part for pair in node.value for part in pair]
    return []


def load_yaml(data: bytes) -> Any:
    """`yaml.safe_load`, bounded (see the module docstring). Raises yaml.YAMLError for bad YAML
    and ImitationError for a document above the bound."""
    loader = _BoundedLoader(data)  # a SafeLoader: builds plain values only
    try:
        return loader.get_single_data()
    finally:
        loader.dispose()


def read_yaml_file(path: Path, kind: str) -> Any:
    """The YAML of a user's `kind` of file (a map, a layout), bounded as `load_yaml`;
    ImitationError names the file and what is wrong."""
    try:
        with open_input(path) as stream:
            data = stream.read()
    except OSError as error:
        raise ImitationError(f"{path}: cannot read the {kind}: {error.strerror or error}") from None
    try:
        return load_yaml(data)  # bytes: yaml reports text that is not UTF-8 as a YAMLError
    except yaml.YAMLError as error:
        raise ImitationError(f"{path}: not valid YAML ({' '.join(str(error).split())[:300]})") from None
    except RecursionError:
        raise ImitationError(f"{path}: not a {kind} (YAML nested too deep)") from None
    except ImitationError as error:
        raise ImitationError(f"{path}: {error}") from None
