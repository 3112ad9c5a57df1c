"""The README's quick start is the two commands, and its examples use only commands and options
that exist: every ``terrainml ...`` line of its shell blocks and every inline ``terrainml ...``
names a command of the CLI and options that command has."""

import re
import shlex
from pathlib import Path

import pytest
import typer

from terrainml.cli import app

README = Path(__file__).resolve().parents[2] / "README.md"


def examples() -> list[str]:
    text = README.read_text()
    blocks = re.findall(r"```bash\n(.*?)```", text, re.S)
    lines = [ln.strip() for b in blocks for ln in b.splitlines() if ln.strip().startswith("terrainml ")]
    inline = re.findall(r"`(terrainml [^`]+)`", text)
    return lines + inline


def resolve(words: list[str]):
    """The CLI command the words name, and the words after it (groups have ``commands``)."""
    cmd = typer.main.get_command(app)
    rest = list(words)
    while hasattr(cmd, "commands") and rest and not rest[0].startswith("-"):
        assert rest[0] in cmd.commands, f"no command {rest[0]!r} in {' '.join(words)!r}"
        cmd, rest = cmd.commands[rest[0]], rest[1:]
    assert not (hasattr(cmd, "commands") and rest), f"{' '.join(words)!r}: options given to a group"
    return cmd, rest


def test_quick_start_is_the_two_commands():
    text = README.read_text()
    quick = text[text.index("## Quick start"):]
    assert re.search(r"```bash\n(.*?)```", quick, re.S).group(1) == "make demo\nmake test\n"


def test_there_are_examples():
    assert len(examples()) >= 15


@pytest.mark.parametrize("line", examples())
def test_readme_example_uses_existing_commands_and_options(line):
    cmd, rest = resolve(shlex.split(line)[1:])
    known = {o for p in cmd.params for o in (*p.opts, *p.secondary_opts)}
    used = {w.split("=")[0] for w in rest if w.startswith("--")}
    assert used <= known, f"{line!r}: {sorted(used - known)} not options of this command"
