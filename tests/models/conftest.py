"""Fixtures of the models tests (tiny labelled logs, see logs_synth)."""

from __future__ import annotations

from pathlib import Path

import pytest

from logs_synth import write_logs
from shared_cache import shared_dir


@pytest.fixture(scope="session")
def log_dir(tmp_path_factory) -> Path:
    """Two tiny labelled logs per class, written once for every xdist worker."""
    return shared_dir(tmp_path_factory, "models-logs",
                      lambda d: write_logs(d / "logs", runs_per_class=2, seed=0)) / "logs"


@pytest.fixture(scope="session")
def log_dir2(tmp_path_factory) -> Path:
    """One tiny labelled log per class (another seed), written once for every xdist worker."""
    return shared_dir(tmp_path_factory, "models-logs2",
                      lambda d: write_logs(d / "logs2", runs_per_class=1, seed=7)) / "logs2"


@pytest.fixture(scope="session")
def dataset(log_dir):
    from terrainml.pipeline.dataset import build_dataset

    return build_dataset(log_dir, "agrimaro")
