"""``terrainml predict --help`` fits a terminal: at most 50 lines at 80 columns, plain text, and it
points to docs/predict.md, which holds the reference (every source, sink, option and exit code)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
MAX_LINES = 50


def _help_at_80_columns() -> str:
    env = {**os.environ, "COLUMNS": "80", "TERM": "dumb", "NO_COLOR": "1"}
    res = subprocess.run([sys.executable, "-m", "terrainml.cli", "predict", "--help"], capture_output=True,
                         text=True, env=env, timeout=120, check=True)
    return res.stdout


def test_predict_help_fits_50_lines_at_80_columns_and_points_to_the_reference():
    text = _help_at_80_columns()
    lines = text.splitlines()
    assert len(lines) <= MAX_LINES, f"{len(lines)} lines:\n{text}"
    assert max(len(line) for line in lines) <= 80
    flat = " ".join(text.split())
    assert "docs/predict.md" in flat
    # the ROS 2 example names the robot and its topic map
    assert "--robot husky" in flat and "--topics husky_ros2" in flat and "ros2://0" in flat


def test_predict_help_has_no_unrendered_markup():
    text = _help_at_80_columns()
    assert "``" not in text and "`" not in text
    assert not re.search(r"\[/?(bold|red|yellow|green|dim|italic|b|i)\]", text)
    assert ":class:" not in text and ":mod:" not in text and ":func:" not in text


def test_every_predict_option_is_in_the_reference():
    """Each flag of ``predict`` is described in docs/predict.md (the help is short, the reference is not)."""
    text = _help_at_80_columns()
    flags = set(re.findall(r"(--[a-z][a-z0-9-]*)", text)) - {"--help"}
    reference = (ROOT / "docs" / "predict.md").read_text()
    missing = sorted(f for f in flags if f"`{f}" not in reference)
    assert not missing, missing
