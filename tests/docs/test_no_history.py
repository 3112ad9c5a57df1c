"""Docs describe what is: no issue numbers in the README or docs/ (git keeps the history)."""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
ISSUE = re.compile(r"issue #?[0-9]+|#[0-9]{2}\b", re.I)


@pytest.mark.parametrize("md", DOCS, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_no_issue_numbers(md):
    text = re.sub(r"\]\([^)]*\)", "]", md.read_text())  # link targets (anchors) are not prose
    assert not ISSUE.findall(text), f"{md.name}: {ISSUE.findall(text)}"
