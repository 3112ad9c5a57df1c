"""Dataset building (sequential, parallel, Dask), SVM and CV determinism on tiny logs."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from terrainml.evaluation.cv import cross_validate
from terrainml.evaluation.folds import grouped_folds
from terrainml.io.ingest import load_run
from terrainml.pipeline.dataset import (DatasetError, build_dataset, find_logs, ingest_logs, read_windows,
                                      write_windows)
from terrainml.robot import load_robot
from terrainml.models.svm import SVMClassifier
from terrainml.pipeline.train import make_factory

from logs_synth import CLASS_SLIP

SMALL_GRID = {"C_grid": (10.0,), "gamma_grid": ("scale",)}


def test_dataset_from_logs_has_the_true_labels_and_slip(dataset):
    w = dataset.windows
    assert dataset.class_ids == [0, 2, 6]
    assert dataset.class_names == ["pavement", "short_grass", "dry_sand"]
    assert set(w.groups) == {f"c{c}_r{r}_s0" for c in (0, 2, 6) for r in (0, 1)}
    for c in (0, 2, 6):
        # estimated slip of the kept windows is the simulated slip (+-10% per-run spread, noise)
        s = w.X[w.y == c][:, w.channels.index("slip_1")].mean()
        assert s == pytest.approx(CLASS_SLIP[c], abs=0.03 + 0.25 * CLASS_SLIP[c])
    assert dataset.counts["n_kept"] == len(w) > 20
    assert dataset.counts["n_windows"] == dataset.counts["n_kept"] + dataset.counts["n_rejected"]
    assert (dataset.runs["status"] == "ok").all()


def test_parquet_round_trip_and_fingerprint(dataset, tmp_path):
    p = write_windows(dataset, tmp_path / "w.parquet")
    back = read_windows(p)
    np.testing.assert_array_equal(back.windows.X, dataset.windows.X)
    assert back.windows.channels == dataset.windows.channels
    assert back.fingerprint == dataset.fingerprint
    assert back.counts == dataset.counts
    with pytest.raises(DatasetError, match="no such windows file"):
        read_windows(tmp_path / "nope.parquet")


def test_find_logs_ignores_index_and_bad_log_is_counted(log_dir, tmp_path):
    d = tmp_path / "mixed"
    d.mkdir()
    for p in sorted(log_dir.glob("*.parquet"))[:2]:
        (d / p.name).write_bytes(p.read_bytes())
    (d / "index.csv").write_text("run_id,terrain\n")
    (d / "zz_broken.parquet").write_bytes(b"PAR1 this is not parquet")
    logs = find_logs(d)
    assert [p.name for p in logs][-1] == "zz_broken.parquet" and len(logs) == 3
    ds = build_dataset(d, "agrimaro")
    st = ds.runs.set_index("source")["status"]
    assert st["zz_broken.parquet"] != "ok" and (st.drop("zz_broken.parquet") == "ok").all()


def test_logs_read_in_parallel_are_each_logs_own_table_in_path_order_and_a_bad_log_is_named(log_dir, tmp_path):
    d = tmp_path / "mixed"
    d.mkdir()
    for p in sorted(log_dir.glob("*.parquet"))[:3]:
        (d / p.name).write_bytes(p.read_bytes())
    (d / "m_broken.parquet").write_bytes(b"PAR1 this is not parquet")
    robot, logs = load_robot("agrimaro"), find_logs(d)
    seen = []
    tables, bad = ingest_logs(logs, robot, n_jobs=2, progress=lambda k, n, name: seen.append((k, n, name)))
    good = [p for p in logs if p.name != "m_broken.parquet"]
    assert len(tables) == 3 and len(bad) == 1 and bad[0].startswith("m_broken.parquet: ")
    for p, t in zip(good, tables):  # each log's own table, as the ingest engine reads it alone
        pd.testing.assert_frame_equal(t, load_run(p, robot=robot).table)
    assert seen == [(k + 1, 4, p.name) for k, p in enumerate(logs)]


def test_parallel_and_dask_builds_equal_sequential(log_dir, dataset):
    distributed = pytest.importorskip("distributed")
    par = build_dataset(log_dir, "agrimaro", n_jobs=2)
    assert par.fingerprint == dataset.fingerprint
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        dk = build_dataset(log_dir, "agrimaro", dask_address=cluster.scheduler_address)
    assert dk.fingerprint == dataset.fingerprint
    np.testing.assert_array_equal(dk.windows.X, dataset.windows.X)
    pd.testing.assert_frame_equal(dk.windows.meta, dataset.windows.meta)
    pd.testing.assert_frame_equal(dk.runs, dataset.runs)


def test_svm_cv_same_seed_same_predictions_and_classes_from_data(dataset):
    w = dataset.windows
    f = make_factory("svm", dataset, seed=4, params=SMALL_GRID)
    a = cross_validate(f, w, w.y, w.groups, folds=grouped_folds(w.y, w.groups, 3, 4))
    b = cross_validate(f, w, w.y, w.groups, folds=grouped_folds(w.y, w.groups, 3, 4))
    np.testing.assert_array_equal(a.y_pred, b.y_pred)
    np.testing.assert_array_equal(a.proba, b.proba)
    assert a.summary["balanced_accuracy"]["mean"] >= 0.9  # classes are well separated by construction
    # foreign class ids (e.g. a real dataset's classes) are taken from the data
    y2 = np.where(w.y == 0, 10, np.where(w.y == 2, 20, 30))
    m = SVMClassifier(**SMALL_GRID).fit(w, y2)
    assert m.classes_.tolist() == [10, 20, 30]
    p = m.predict_proba(w)
    np.testing.assert_allclose(p.sum(axis=1), 1.0)
    np.testing.assert_array_equal(m.predict(w), m.classes_[p.argmax(axis=1)])
    assert set(m.best_params_) == {"C", "gamma"}


def test_fast_probabilities_equal_sklearn_calibrated_path(dataset):
    """The stream's one-window path must serve exactly what sklearn's calibrated model gives."""
    w = dataset.windows
    m = SVMClassifier(**SMALL_GRID).fit(w, w.y)
    ref = m.model_.predict_proba(m.transform_features(w))
    np.testing.assert_allclose(m.predict_proba(w), ref, rtol=0, atol=1e-12)
    one = np.asarray(w.X)[:1]
    np.testing.assert_allclose(m.predict_proba(one), ref[:1], rtol=0, atol=1e-12)
