"""Shared fixtures of the real-data tests: the BorealTC folder and the ROS 1 bag, read once."""

from pathlib import Path

import pytest

SHARED = Path(__file__).resolve().parents[2].parent / "shared" / "datasets"
BOREAL = SHARED / "borealtc"
BAG = SHARED / "robot_localization_husky" / "test1.bag"


@pytest.fixture(scope="session")
def boreal_tables():
    if not BOREAL.is_dir():
        pytest.skip(f"real dataset not present at {BOREAL}")
    from terrainml.io.ingest import load_dataset

    tables, report = load_dataset("borealtc", BOREAL)
    return tables, report


@pytest.fixture(scope="session")
def boreal_windows(boreal_tables):
    """Chunks and a light window set (6 windows per chunk of the smallest class)."""
    from terrainml.experiments.borealtc import chunk_windows, make_chunks

    tables, _ = boreal_tables
    chunks = make_chunks(tables, chunk_s=5.0)
    return chunks, chunk_windows(tables, chunks, window_s=1.7, max_windows_per_chunk=6)
