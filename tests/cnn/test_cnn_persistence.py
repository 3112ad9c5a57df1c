"""CNN persistence (safetensors + JSON, no pickle) and ONNX parity."""

from __future__ import annotations

import json
import pickle

import numpy as np
import pytest
import torch

from terrainml.models.cnn import CNNClassifier
from terrainml.models.cnn_files import CONFIG_NAME, WEIGHTS_NAME
from terrainml.models.onnx_export import OnnxCNN, export_onnx


def _forbid_unpickling(monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("unpickling attempted")

    monkeypatch.setattr(torch, "load", refuse)
    monkeypatch.setattr(pickle, "load", refuse)
    monkeypatch.setattr(pickle, "loads", refuse)


def test_save_load_roundtrip_gives_identical_probabilities(fitted, tmp_path, monkeypatch):
    clf, X, y, g, train = fitted
    files = clf.save(tmp_path / "model")
    assert sorted(p.name for p in files) == sorted([WEIGHTS_NAME, CONFIG_NAME])
    assert all(p.is_file() for p in files)
    cfg = json.loads((tmp_path / "model" / CONFIG_NAME).read_text())
    assert cfg["classes"] == [0, 1, 2]
    assert cfg["architecture"]["n_channels"] == X.shape[1]
    assert len(cfg["normalisation"]["mean"]) == X.shape[1]

    _forbid_unpickling(monkeypatch)
    loaded = CNNClassifier.load(tmp_path / "model")
    Xq = X[~train].copy()
    Xq[0, 3, 10:40] = np.nan
    assert np.array_equal(loaded.predict_proba(Xq), clf.predict_proba(Xq))
    assert np.array_equal(loaded.classes_, clf.classes_)
    assert loaded.channel_names_ == clf.channel_names_
    assert loaded.get_params() == clf.get_params()


@pytest.mark.parametrize("window_stats", [True, False])
def test_roundtrip_keeps_string_classes_and_architecture(window_factory, tmp_path, window_stats):
    X, y, g = window_factory(n_classes=2, n_channels=4, runs_per_class=3, windows_per_run=4,
                             kind="mean", seed=2)
    labels = np.array(["dry_sand", "pavement"])[y]
    clf = CNNClassifier.from_params(random_state=0, max_epochs=2, n_threads=1, window_stats=window_stats,
                        conv_channels=(8, 16), kernel_sizes=(5, 3)).fit(X, labels, g)
    clf.save(tmp_path)
    loaded = CNNClassifier.load(tmp_path)
    assert list(loaded.classes_) == ["dry_sand", "pavement"]
    assert np.array_equal(loaded.predict_proba(X), clf.predict_proba(X))
    sess = OnnxCNN(export_onnx(clf, tmp_path / "m.onnx"))
    np.testing.assert_allclose(sess.predict_proba(X), clf.predict_proba(X), rtol=0, atol=1e-5)


def test_load_refuses_damaged_files_naming_them(fitted, tmp_path):
    clf, *_ = fitted
    clf.save(tmp_path)
    cfg_path = tmp_path / CONFIG_NAME
    cfg = json.loads(cfg_path.read_text())
    cfg["architecture"]["conv_channels"] = [16, 16, 16]
    cfg_path.write_text(json.dumps(cfg))
    with pytest.raises(ValueError, match=WEIGHTS_NAME):
        CNNClassifier.load(tmp_path)
    cfg_path.write_text("{not json")
    with pytest.raises(ValueError, match=CONFIG_NAME):
        CNNClassifier.load(tmp_path)
    cfg_path.unlink()
    with pytest.raises(ValueError, match=CONFIG_NAME):
        CNNClassifier.load(tmp_path)


def test_onnx_probabilities_match_torch(fitted, tmp_path, monkeypatch):
    clf, X, y, g, train = fitted
    path = export_onnx(clf, tmp_path / "cnn.onnx")
    _forbid_unpickling(monkeypatch)
    session = OnnxCNN(path, n_threads=1)
    assert np.array_equal(session.classes_, clf.classes_)
    assert session.channel_names_ == clf.channel_names_
    Xq = X[~train].copy()
    Xq[1, 0, :] = np.nan  # a missing channel is handled inside the graph too
    for batch in (Xq[:1], Xq):
        np.testing.assert_allclose(session.predict_proba(batch), clf.predict_proba(batch), rtol=0, atol=1e-5)
    assert np.array_equal(session.predict(Xq), clf.predict(Xq))
    with pytest.raises(ValueError, match="shape"):
        session.predict_proba(Xq[:, :3])
