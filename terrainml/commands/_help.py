"""Help texts shared by the commands, naming the built-in robots, topic maps and window specs
from their registries, so that the help says what the code holds.

The registries imported here are plain names (no numpy, no pandas), so ``terrainml --help`` stays
light (``tests/test_cli_startup.py``).
"""

from __future__ import annotations

from collections.abc import Iterable

from terrainml.features.window_presets import DEFAULT_WINDOWS, WINDOW_SPEC_SUMMARIES
from terrainml.io.topicmap_names import BUILTIN_MAPS
from terrainml.robots import BUILTIN_ROBOTS, REFERENCE_ROBOT


def listed(names: Iterable[str]) -> str:
    """``a, b, c``: the names of a registry, as a help text lists them."""
    return ", ".join(names)


def robot_help(default: str | None = REFERENCE_ROBOT) -> str:
    """The ``--robot`` help: the built-in robots and what a command given no robot uses (None: an
    option whose default typer shows itself)."""
    text = f"Robot spec: a YAML path or a built-in name ({listed(BUILTIN_ROBOTS)})."
    return text if default is None else f"{text} Default: {default}."


def topics_help(default: str = "default (the design §5 map)") -> str:
    """The ``--topics`` help: the built-in topic maps and what a command given no map uses."""
    return f"Topic map: a YAML path or a built-in name ({listed(BUILTIN_MAPS)}). Default: {default}."


#: the ``--windows`` help: every named window spec with what it cuts, and the default
WINDOWS_HELP = ("Window spec: " + "; ".join(f"{name} ({summary})" for name, summary in WINDOW_SPEC_SUMMARIES.items())
                + f". Default: {DEFAULT_WINDOWS}.")

#: the default window spec in a phrase, e.g. for a group's one-line help
DEFAULT_WINDOWS_PHRASE = f"{DEFAULT_WINDOWS} spec by default: {WINDOW_SPEC_SUMMARIES[DEFAULT_WINDOWS]}"
