"""The ``terrainml`` command tree as the tests in this folder read it: every command path with its
click command, the help each renders, and the examples the help texts and the README give.

Nothing here runs a command's work: the commands are looked up in the click objects that
``typer.main.get_command`` builds from the app.
"""

from __future__ import annotations

import re
import shlex
from collections.abc import Iterator
from pathlib import Path

import typer
from typer.testing import CliRunner

from terrainml.cli import app

ROOT = typer.main.get_command(app)
README = Path(__file__).resolve().parents[2] / "README.md"

#: a help paragraph that is an example: ``Example: terrainml ...``, ``Example (what): terrainml ...``,
#: or a bare ``terrainml ...`` (under an ``Examples:`` heading)
_EXAMPLE_PARAGRAPH = re.compile(r"^(?:(?:Examples?(?: \([^)]*\))?|Quick start): )?(?P<command>(?:``)?terrainml .*)$",
                                re.DOTALL)
#: a command quoted in prose: ```terrainml ...```
_QUOTED_COMMAND = re.compile(r"(?<!`)`(terrainml(?: [^`]*)?)`(?!`)")


def command_paths(cmd=ROOT, prefix: tuple[str, ...] = ()) -> Iterator[tuple[tuple[str, ...], object]]:
    """Every command and group below ``cmd`` (itself first), with its path of names."""
    yield prefix, cmd
    # a group has sub-commands (typer carries its own click: no isinstance on click.Group)
    for name in sorted(getattr(cmd, "commands", None) or {}):
        yield from command_paths(cmd.commands[name], prefix + (name,))


def render_help(path: tuple[str, ...], columns: int = 80) -> str:
    """What ``terrainml PATH --help`` prints in a terminal ``columns`` wide."""
    res = CliRunner().invoke(app, [*path, "--help"], env={"COLUMNS": str(columns)}, prog_name="terrainml")
    assert res.exit_code == 0, f"terrainml {' '.join(path)} --help: exit {res.exit_code}\n{res.output}"
    return res.output


def help_examples(cmd) -> list[str]:
    """The examples in ``cmd``'s help: each example paragraph's command (``Example...: terrainml ...``
    or a bare ``terrainml ...``), and every ```terrainml ...``` quoted in its help or in its
    parameters' help."""
    examples = [m["command"] for p in (cmd.help or "").split("\n\n")
                if (m := _EXAMPLE_PARAGRAPH.match(p.strip()))]
    texts = [cmd.help or ""] + [getattr(p, "help", None) or "" for p in cmd.params]
    return examples + [m for text in texts for m in _QUOTED_COMMAND.findall(text)]


def readme_examples(text: str | None = None) -> list[str]:
    """The ``terrainml`` commands of the README: the lines of its code blocks that start with
    ``terrainml`` (continued over ``\\`` line ends) and the ```terrainml ...``` quoted in its prose."""
    text = README.read_text(encoding="utf-8") if text is None else text
    found: list[str] = []
    in_block = False
    pending = ""
    for line in text.splitlines():
        if line.lstrip().startswith("```"):
            in_block = not in_block
            continue
        if in_block:
            stripped = pending + line.strip().removeprefix("$ ")
            pending = ""
            if stripped.endswith("\\"):
                pending = stripped[:-1].rstrip() + " "
            elif stripped.startswith("terrainml "):
                found.append(stripped)
        else:
            found.extend(_QUOTED_COMMAND.findall(line))
    return found


def check_example(example: str) -> list[str]:
    """What is wrong with ``example`` as a command line of this app (empty: nothing).

    The command path must exist, and every ``--option`` (or ``-o``) it names must be an option of
    the command it reaches; values and arguments are not checked.
    """
    try:
        tokens = shlex.split(example)
    except ValueError as exc:
        return [f"not a command line ({exc})"]
    if not tokens or tokens[0] != "terrainml":
        return ["does not start with `terrainml `"]
    cmd, rest, path = ROOT, tokens[1:], ["terrainml"]
    while rest and rest[0] in (getattr(cmd, "commands", None) or {}):
        cmd = cmd.commands[rest[0]]
        path.append(rest.pop(0))
    if getattr(cmd, "commands", None) and rest and not rest[0].startswith("-"):
        return [f"`{' '.join(path)}` has no command {rest[0]!r}"]
    problems = []
    known = {"--help"} | {o for p in cmd.params for o in (*p.opts, *p.secondary_opts) if o.startswith("-")}
    for tok in rest:
        if not tok.startswith("-") or re.fullmatch(r"-[\d.]+", tok) or tok in ("-", "--"):
            continue   # an argument, a value, or a negative number (--n-jobs -1)
        if tok.split("=", 1)[0] not in known:
            problems.append(f"`{' '.join(path)}` has no option {tok.split('=', 1)[0]}")
    return problems
