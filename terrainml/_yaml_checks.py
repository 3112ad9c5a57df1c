"""Reading a user's YAML file with errors that name the file (design §3, §5).

Robot specs, topic maps, dataset specs, terrain catalogues and dataset recipes are all
hand-written YAML; a missing file or a syntax error must surface as the caller's own error type,
with the path first, never a bare yaml traceback.

Every YAML the project reads is **bounded** (:func:`load_bounded_yaml`): at most
``MAX_YAML_BYTES`` of text, ``MAX_YAML_ALIASES`` alias references and ``MAX_YAML_NODES`` nodes
once every alias is expanded, and no alias that contains itself. An alias bomb ("billion
laughs": a few lines whose aliases expand to 10^9 nodes) is then refused in milliseconds naming
the file, instead of exhausting memory later wherever the document is walked.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import Any

import yaml

#: largest YAML file read (bytes): a spec is a few kB
MAX_YAML_BYTES = 1 << 20
#: most alias references (``*name``) in one document
MAX_YAML_ALIASES = 1000
#: most nodes in one document with every alias expanded (what a consumer walking it meets)
MAX_YAML_NODES = 200_000


class YamlLimitError(yaml.YAMLError):
    """A YAML document beyond the limits of :func:`load_bounded_yaml` (the message says which)."""


def _expanded_nodes(root: yaml.Node) -> tuple[int, int]:
    """(nodes with every alias expanded, alias references) of a composed document; iterative.

    Raises YamlLimitError past ``MAX_YAML_NODES`` or on an alias that contains itself.
    """
    size: dict[int, int] = {}
    refs = 0
    seen_once: set[int] = set()
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    on_path: set[int] = set()
    while stack:
        node, done = stack.pop()
        key = id(node)
        if done:
            on_path.discard(key)
            kids = _children(node)
            size[key] = 1 + sum(size[id(k)] for k in kids)
            if size[key] > MAX_YAML_NODES:
                raise YamlLimitError(f"more than {MAX_YAML_NODES} nodes once its aliases are expanded "
                                     "(an alias bomb?)")
            continue
        if key in seen_once:
            refs += 1
            if key in on_path:
                raise YamlLimitError("an alias that contains itself (a recursive document)")
            if refs > MAX_YAML_ALIASES:
                raise YamlLimitError(f"more than {MAX_YAML_ALIASES} alias references")
            continue
        seen_once.add(key)
        on_path.add(key)
        stack.append((node, True))
        stack.extend((k, False) for k in _children(node))
    return size[id(root)], refs


def _children(node: yaml.Node) -> list[yaml.Node]:
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    if isinstance(node, yaml.MappingNode):
        return [n for pair in node.value for n in pair]
    return []


def load_bounded_yaml(text: str, loader: type[yaml.SafeLoader] = yaml.SafeLoader) -> Any:
    """Parse one YAML document within the limits above (``loader``: a SafeLoader subclass).

    Raises
    ------
    yaml.YAMLError
        Malformed YAML, or :class:`YamlLimitError` for a document beyond a limit.
    """
    if len(text) > MAX_YAML_BYTES:
        raise YamlLimitError(f"larger than {MAX_YAML_BYTES} bytes ({len(text)})")
    ld = loader(text)
    try:
        node = ld.get_single_node()
        if node is None:
            return None
        _expanded_nodes(node)
        return ld.construct_document(node)
    finally:
        ld.dispose()


def read_yaml_file(path: Path, error: type[Exception], not_found: str) -> Any:
    """Parse the YAML file at ``path``; raise ``error`` if it is missing (message ``not_found``),
    malformed or beyond the limits of :func:`load_bounded_yaml` (the message names ``path``)."""
    if not path.is_file():
        raise error(not_found)
    try:
        if path.stat().st_size > MAX_YAML_BYTES:
            raise YamlLimitError(f"larger than {MAX_YAML_BYTES} bytes ({path.stat().st_size})")
        return load_bounded_yaml(path.read_text())
    except YamlLimitError as exc:
        raise error(f"{path}: refused: {exc}") from None
    except yaml.YAMLError as exc:
        raise error(f"{path}: not valid YAML: {exc}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise error(f"{path}: cannot read the file ({exc})") from None


def read_builtin_yaml(package: str, folder: str, name: str) -> Any:
    """Parse the YAML file ``folder/name.yaml`` shipped inside ``package`` (a built-in spec)."""
    return load_bounded_yaml(resources.files(package).joinpath(folder, f"{name}.yaml").read_text())
