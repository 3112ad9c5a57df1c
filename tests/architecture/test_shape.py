"""The shape a newcomer reads as reference: short modules, few parameters, one name per module, no history.

These are the structural rules of the design (design §2): every module of the package is at most
600 lines; no function outside ``terrainml/commands/`` takes more than 10 parameters (``self`` and
``cls`` not counted), except numba kernels, which take flat arrays and scalars and say so in their
docstring; no two modules share a file name; ``docs/design.md`` is at most 600 lines and the README
at most 150; neither the package, its tests and benchmarks nor the docs cite issue numbers (git keeps the history).
"""

from __future__ import annotations

import ast
import re
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "terrainml"
MAX_MODULE_LINES = 600
MAX_PARAMETERS = 10
ISSUE_NUMBER = re.compile(r"issue #?[0-9]+|#[0-9]{2}\b", re.IGNORECASE)


def _modules() -> list[Path]:
    return sorted(p for p in PACKAGE.rglob("*.py") if "__pycache__" not in p.parts)


def _n_parameters(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    a = fn.args
    names = [x.arg for x in a.posonlyargs + a.args]
    n = len(names) + len(a.kwonlyargs) + (a.vararg is not None) + (a.kwarg is not None)
    return n - (1 if names and names[0] in ("self", "cls") else 0)


def _is_numba_kernel(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> bool:
    decorated = any("jit" in ast.unparse(d) for d in fn.decorator_list)
    return decorated and "numba" in (ast.get_docstring(fn) or "").lower()


def test_no_module_is_over_600_lines():
    long = {str(p.relative_to(ROOT)): n for p in _modules()
            if (n := len(p.read_text().splitlines())) > MAX_MODULE_LINES}
    assert not long, f"modules over {MAX_MODULE_LINES} lines: {long}"


def test_no_function_outside_the_commands_takes_more_than_10_parameters():
    wide = []
    for path in _modules():
        if "commands" in path.relative_to(PACKAGE).parts:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and not _is_numba_kernel(node):
                if (n := _n_parameters(node)) > MAX_PARAMETERS:
                    wide.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name} ({n})")
    assert not wide, "functions with more than 10 parameters:\n" + "\n".join(wide)


def test_no_two_modules_share_a_file_name():
    names = Counter(p.name for p in _modules() if p.name != "__init__.py")
    shared = {n: [str(p.relative_to(ROOT)) for p in _modules() if p.name == n] for n, c in names.items() if c > 1}
    assert not shared, f"file names used by more than one module: {shared}"


def test_the_design_and_the_readme_are_short_enough_to_read():
    assert len((ROOT / "docs" / "design.md").read_text().splitlines()) <= 600
    assert len((ROOT / "README.md").read_text().splitlines()) <= 150


def test_neither_code_nor_docs_cite_issue_numbers():
    files = (_modules() + sorted((ROOT / "tests").rglob("*.py")) + sorted((ROOT / "benchmarks").rglob("*.py"))
             + sorted((ROOT / "docs").rglob("*.md")) + [ROOT / "README.md", ROOT / "BENCHMARKS.md"])
    hits = [f"{p.relative_to(ROOT)}:{i}: {line.strip()}" for p in files
            for i, line in enumerate(p.read_text().splitlines(), 1) if ISSUE_NUMBER.search(line)]
    assert not hits, "issue numbers (git keeps the history):\n" + "\n".join(hits)
