"""The layers contract (design §2) and the linter run in `make test`; a deliberate back-import must fail.

`lint-imports` reads the contract from pyproject.toml. To prove the contract can fail, the package is
copied to a temporary folder, a module of the io layer is given an import of the simulator (the
chain must never import sim), and lint-imports is run against the copy, which then shadows the
installed package on PYTHONPATH.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
LINT_IMPORTS = Path(sys.executable).with_name("lint-imports")


def _lint(package_parent: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(package_parent))
    return subprocess.run([str(LINT_IMPORTS), "--config", str(ROOT / "pyproject.toml"), "--no-cache"],
                          cwd=package_parent, env=env, capture_output=True, text=True, timeout=300)


def _copy_package(tmp_path: Path) -> Path:
    shutil.copytree(ROOT / "terrainml", tmp_path / "terrainml",
                    ignore=shutil.ignore_patterns("__pycache__", "*.nbi", "*.nbc"))
    return tmp_path


def test_the_repository_keeps_the_layers_contract():
    res = _lint(ROOT)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "0 broken" in res.stdout


@pytest.mark.parametrize(("layer", "import_line", "importer", "imported"), [
    ("io", "import terrainml.sim  # noqa: F401", "terrainml.io", "terrainml.sim"),
    ("estimation", "from terrainml.stream.tick import message  # noqa: F401", "terrainml.estimation",
     "terrainml.stream"),
], ids=["chain-into-sim", "lower-into-higher"])
def test_a_back_import_breaks_the_contract(tmp_path, layer, import_line, importer, imported):
    """A module of a lower layer importing the simulator or a higher layer makes lint-imports fail."""
    parent = _copy_package(tmp_path)
    module = parent / "terrainml" / layer / "_back_import.py"
    module.write_text(f'"""A deliberate violation."""\n\n{import_line}\n')
    res = _lint(parent)
    assert res.returncode != 0
    assert f"{importer} is not allowed to import {imported}" in res.stdout
    assert f"{importer}._back_import -> {imported}" in res.stdout
