"""Shared test setup: ``tests/`` on ``sys.path`` so area folders can import shared helpers
(``synthetic_runs``) by module name."""

import sys
from pathlib import Path

_TESTS = str(Path(__file__).resolve().parent)
if _TESTS not in sys.path:
    sys.path.insert(0, _TESTS)
