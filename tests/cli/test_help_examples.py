"""Every example runs as written: each ``terrainml ...`` command given in a help text or in the
README names a command that exists and only options that command has.

The commands are looked up in the app's click objects (:func:`cli_tree.check_example`); no work
is run.
"""

from __future__ import annotations

import re

import pytest
from cli_tree import check_example, command_paths, help_examples, readme_examples

#: commands whose examples are not yet plain command lines: none
_NOT_YET_PLAIN: dict[str, str] = {}

#: README examples that do not run as written today (the README is being rewritten): none
_README_KNOWN_BAD: dict[str, str] = {}

#: commands whose help needs no example (no option to show)
_NO_EXAMPLE_NEEDED = {("version",)}


def _help_cases():
    for path, cmd in command_paths():
        name = " ".join(path)
        for i, example in enumerate(help_examples(cmd)):
            bad = name in _NOT_YET_PLAIN and example.startswith("``")
            marks = [pytest.mark.xfail(strict=False, reason=_NOT_YET_PLAIN[name])] if bad else []
            yield pytest.param(example, id=f"{name or 'terrainml'}[{i}]", marks=marks)


def _readme_cases():
    for i, example in enumerate(readme_examples()):
        marks = ([pytest.mark.xfail(strict=False, reason=_README_KNOWN_BAD[example])]
                 if example in _README_KNOWN_BAD else [])
        yield pytest.param(example, id=f"README[{i}]", marks=marks)


@pytest.mark.parametrize("example", list(_help_cases()))
def test_help_example_runs_as_written(example):
    """A help text's example: its command exists and has every option it names."""
    assert check_example(example) == [], example


@pytest.mark.parametrize("example", list(_readme_cases()))
def test_readme_example_runs_as_written(example):
    """A README example: its command exists and has every option it names."""
    assert check_example(example) == [], example


def test_help_and_readme_have_examples():
    """The walk finds examples: in the README, and in the help of every command but ``version``."""
    assert len(readme_examples()) >= 5
    missing = [path for path, cmd in command_paths()
               if path and not getattr(cmd, "commands", None) and path not in _NO_EXAMPLE_NEEDED
               and not any(e.startswith(("terrainml " + " ".join(path), "``terrainml " + " ".join(path)))
                           for e in help_examples(cmd))]
    assert missing == []


def test_check_example_finds_mistakes():
    """The check itself: a wrong command, sub-command or option is named; a right one passes."""
    assert check_example("terrainml ingset run.mcap") == ["`terrainml` has no command 'ingset'"]
    assert check_example("terrainml lookup shwo --json") == ["`terrainml lookup` has no command 'shwo'"]
    assert check_example("terrainml ingest run.mcap --out r.parquet --robo husky") == [
        "`terrainml ingest` has no option --robo"]
    assert check_example("``terrainml demo``") == ["does not start with `terrainml `"]
    assert check_example("terrainml sim generate --runs-per-class 1 --n-jobs -1 --no-brake --out=x") == []
    assert check_example("terrainml dataset build d -o w.parquet -j 2") == []


def test_readme_examples_read_blocks_and_quotes():
    """Commands come from code blocks (``$ `` prompts and ``\\`` continuations too) and from quotes."""
    text = ("Run `terrainml inspect LOG` first.\n\n```bash\n$ terrainml ingest a.mcap \\\n  --out a.parquet\n"
            "make demo\n```\n\n```\n-> ingest    terrainml ingest | inspect\n```\n")
    assert readme_examples(text) == ["terrainml inspect LOG", "terrainml ingest a.mcap --out a.parquet"]
    assert all(re.match(r"terrainml( |$)", e) for e in readme_examples())
