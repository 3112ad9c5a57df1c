"""The CLI starts light: ``terrainml --help``, ``terrainml version`` and every subcommand's
``--help`` import none of the heavy stack (pandas, scipy, sklearn, numba, torch, pyarrow, mcap,
cyclonedds); each command imports what it needs when it runs.

The check runs in a fresh interpreter (this test process has most of the stack imported already),
walks the real command tree, and reads ``sys.modules`` afterwards: it asserts what is imported,
not a timing, so a loaded machine cannot make it flaky (``benchmarks/bench_cli.py`` measures time).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

#: top-level packages that take a noticeable share of a second each to import
HEAVY = ("pandas", "scipy", "sklearn", "numba", "torch", "pyarrow", "mcap", "cyclonedds")

_PROBE = r"""
import json, sys
import typer
from typer.testing import CliRunner
import terrainml.cli

root = typer.main.get_command(terrainml.cli.app)

def paths(cmd, prefix):
    yield prefix
    # a group has sub-commands (typer carries its own click: no isinstance on click.Group)
    for name in sorted(getattr(cmd, "commands", None) or {}):
        yield from paths(cmd.commands[name], prefix + [name])

runner = CliRunner()
calls = [["--help"], ["version"]] + [p + ["--help"] for p in paths(root, []) if p]
results = []
for args in calls:
    r = runner.invoke(terrainml.cli.app, args)
    results.append({"args": args, "exit_code": r.exit_code, "output": r.output[-300:],
                    "exception": repr(r.exception) if r.exception and r.exit_code else None})
heavy = sys.argv[1].split(",")
loaded = sorted(h for h in heavy if h in sys.modules)
print(json.dumps({"results": results, "loaded": loaded}))
"""


@pytest.fixture(scope="module")
def probe() -> dict:
    """Run every ``--help`` and ``version`` in one fresh interpreter; its calls and the heavy
    packages it ended up importing."""
    root = Path(__file__).resolve().parents[1]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.run([sys.executable, "-c", _PROBE, ",".join(HEAVY)], capture_output=True, text=True,
                          env=env, cwd=root, timeout=120)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_every_help_and_version_succeed(probe):
    """Every call exits 0; the walk found the nested commands too (not only the root)."""
    args = [tuple(r["args"]) for r in probe["results"]]
    assert ("version",) in args and ("train", "--help") in args and ("predict", "--help") in args
    assert any(len(a) == 3 for a in args), "no nested sub-app command (e.g. `model sign --help`) was visited"
    failed = [(r["args"], r["exit_code"], r["exception"] or r["output"]) for r in probe["results"]
              if r["exit_code"] != 0]
    assert not failed
    version = next(r for r in probe["results"] if r["args"] == ["version"])
    from terrainml import __version__

    assert version["output"].strip() == __version__


def test_help_and_version_import_no_heavy_package(probe):
    """None of the heavy packages is imported by the whole walk."""
    assert probe["loaded"] == []
