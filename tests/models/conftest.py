"""Fixtures of the models tests (tiny labelled logs, see logs_synth)."""

from __future__ import annotations

from pathlib import Path

import pytest

from logs_synth import write_logs


@pytest.fixture(scope="session")
def log_dir(tmp_path_factory) -> Path:
    return write_logs(tmp_path_factory.mktemp("logs"), runs_per_class=2, seed=0)


@pytest.fixture(scope="session")
def log_dir2(tmp_path_factory) -> Path:
    return write_logs(tmp_path_factory.mktemp("logs2"), runs_per_class=1, seed=7)


@pytest.fixture(scope="session")
def dataset(log_dir):
    from terrainml.pipeline.dataset import build_dataset

    return build_dataset(log_dir, "agrimaro")
