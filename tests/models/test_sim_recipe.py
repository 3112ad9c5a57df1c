"""The simulated-dataset recipe end to end (simulator -> logs -> ingest -> EKF -> windows), cached."""

from __future__ import annotations

import time

from terrainml.classes import TERRAIN_CLASSES
from terrainml.experiments.recipes import load_recipe, simulated_dataset


def test_default_recipe_meets_the_issue_size():
    r = load_recipe("sim_default")
    assert r["runs_per_class"] >= 12 and r["seed"] == 0
    assert len(r["scenarios"]) >= 3


def test_tiny_recipe_builds_labelled_windows_and_is_cached(tmp_path):
    recipe = {"name": "tiny", "robot": "agrimaro", "runs_per_class": 1, "seed": 3, "duration_s": 24.0,
              "format": "parquet", "preset": "robust", "window": {"window_s": 2.0, "hop_s": 2.0}}
    ds = simulated_dataset(recipe, n_jobs=2, cache_dir=tmp_path)
    assert len(ds.runs) == 8 and (ds.runs["status"] == "ok").all()
    assert len(ds.windows) > 0
    # labels are the simulated classes: every window's label is the class in its run id
    for rid, lab in zip(ds.windows.groups, ds.windows.y):
        assert TERRAIN_CLASSES[lab] in rid
    t0 = time.perf_counter()
    again = simulated_dataset(recipe, n_jobs=2, cache_dir=tmp_path)
    assert again.fingerprint == ds.fingerprint
    assert time.perf_counter() - t0 < 10
