"""Train -> artifact -> verified load; tampering refused naming the file; CLI train/evaluate."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from terrainml.models import artifacts
from terrainml.models.artifacts import ArtifactError, load_artifact
from terrainml.pipeline.evaluate import evaluate
from terrainml.pipeline.train_options import TrainOptions
from terrainml.pipeline.train import served_table, train

SMALL = {"svm": {"C_grid": (10.0,), "gamma_grid": ("scale",)},
         "cnn": {"max_epochs": 2, "conv_channels": (4, 4, 4), "patience": 1}}


@pytest.fixture(scope="module")
def trained(dataset, tmp_path_factory):
    out = tmp_path_factory.mktemp("runs") / "both"
    res = train(dataset, out, models=("svm", "cnn"), options=TrainOptions(folds=3, seed=0, ablation=True,
                                                                             model_params=SMALL))
    return out, res


def test_train_writes_verified_artifact_and_report(trained, dataset):
    out, res = trained
    files = {p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()}
    for f in ("manifest.json", "svm/model.skops", "cnn/cnn_weights.safetensors", "cnn/cnn_config.json",
              "desired_slip_table.json", "report.md", "report.json", "confusion_svm.png",
              "confusion_cnn.png", "folds_svm.csv", "folds_cnn.csv", "ablation.csv"):
        assert f in files, f
    man = json.loads((out / "manifest.json").read_text())
    assert set(man["files"]) == files - {"manifest.json"}
    assert man["classes"] == [0, 2, 6] and man["class_names"] == ["pavement", "short_grass", "dry_sand"]
    assert man["training_fingerprint"] == dataset.fingerprint
    assert man["channels"] == list(dataset.windows.channels)
    assert man["robot"]["sha256"] == dataset.robot.sha256()
    rep = json.loads((out / "report.json").read_text())
    assert {a["subset"] for a in rep["ablation"]} == {"kinematic", "currents", "imu", "all"}
    assert len(rep["models"]["svm"]["per_fold"]) == 3
    for name in ("svm", "cnn"):
        art = load_artifact(out, name)
        assert art.kind == name and art.attachments == {"desired_slip_table.json": out / "desired_slip_table.json"}
        assert served_table(art) is not None
        p = art.model.predict_proba(dataset.windows)
        assert p.shape == (len(dataset.windows), 3)
        np.testing.assert_allclose(p, res.fitted[name].predict_proba(dataset.windows), rtol=0, atol=1e-6)


def test_loaded_svm_predicts_like_the_trained_one(trained, dataset):
    out, _ = trained
    a = load_artifact(out, "svm")
    b = load_artifact(out, "svm")
    np.testing.assert_array_equal(a.model.predict_proba(dataset.windows), b.model.predict_proba(dataset.windows))
    m = evaluate(out, dataset, "svm")
    assert m["n_windows"] == len(dataset.windows) and m["balanced_accuracy"] >= 0.9


def _copy(src: Path, dst: Path) -> Path:
    import shutil

    shutil.copytree(src, dst)
    return dst


def test_one_flipped_byte_in_any_file_is_refused_naming_the_file(trained, tmp_path):
    out, _ = trained
    rels = sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file())
    rng = np.random.default_rng(0)
    for k, rel in enumerate(rels):
        d = _copy(out, tmp_path / f"c{k}")
        p = d / rel
        data = bytearray(p.read_bytes())
        i = int(rng.integers(len(data)))
        data[i] ^= 0x01
        p.write_bytes(bytes(data))
        with pytest.raises(ArtifactError) as exc:
            load_artifact(d)
        assert rel.split("/")[-1] in str(exc.value), (rel, str(exc.value))


def test_every_byte_position_of_the_manifest_is_protected(trained, tmp_path):
    out, _ = trained
    d = _copy(out, tmp_path / "m")
    p = d / "manifest.json"
    orig = p.read_bytes()
    for i in range(0, len(orig), max(1, len(orig) // 300)):
        data = bytearray(orig)
        data[i] ^= 0x20
        p.write_bytes(bytes(data))
        with pytest.raises(ArtifactError, match="manifest.json"):
            artifacts.read_manifest(d)
    p.write_bytes(orig)
    artifacts.read_manifest(d)


def test_skops_types_outside_the_allow_list_are_refused(trained, tmp_path, monkeypatch):
    out, _ = trained
    untrusted = __import__("skops.io", fromlist=["x"]).get_untrusted_types(file=out / "svm" / "model.skops")
    assert set(untrusted) <= artifacts.ALLOWED_SKOPS_TYPES
    monkeypatch.setattr(artifacts, "ALLOWED_SKOPS_TYPES",
                        artifacts.ALLOWED_SKOPS_TYPES - {"terrainml.features.sets.FeatureSet"})
    with pytest.raises(ArtifactError, match=r"model\.skops.*FeatureSet"):
        load_artifact(out, "svm")


def test_cli_train_and_evaluate(log_dir, log_dir2, tmp_path, monkeypatch):
    from terrainml.cli import app
    from terrainml.pipeline import train as train_mod

    real = train_mod.make_factory
    monkeypatch.setattr(train_mod, "make_factory",
                        lambda kind, ds, seed=0, subset="all", n_jobs=1, params=None:
                        real(kind, ds, seed, subset, n_jobs, {**SMALL[kind], **(params or {})}))
    runner = CliRunner()
    w = tmp_path / "w.parquet"
    r = runner.invoke(app, ["dataset", "build", str(log_dir), "--out", str(w), "-q"])
    assert r.exit_code == 0, r.output
    out = tmp_path / "runs" / "svm"
    r = runner.invoke(app, ["train", "--data", str(w), "--model", "svm", "--folds", "3", "--seed", "1",
                            "--out", str(out), "--no-ablation", "-q"])
    assert r.exit_code == 0, r.output
    rep = tmp_path / "eval.json"
    r = runner.invoke(app, ["evaluate", str(out), "--data", str(log_dir2), "--out", str(rep), "-q"])
    assert r.exit_code == 0, r.output
    m = json.loads(rep.read_text())
    for k in ("balanced_accuracy", "accuracy", "macro_f1", "desired_slip_error_mean", "n_windows"):
        assert k in m
    assert m["balanced_accuracy"] >= 0.9 and m["n_windows"] > 5
    # logs with labels are also served tick by tick; every moving tick is accounted for once
    rp = m["served_replay"]
    assert rp["runs"] == 3 and rp["moving_ticks"] > 0
    assert sum(rp["losses"]["kinds"].values()) == rp["losses"]["moving_ticks"] == rp["moving_ticks"]
    assert rp["right_share"] == rp["losses"]["kinds"]["right"] / rp["moving_ticks"]
    # the classes are told apart by construction: the windows and the served class are mostly right
    assert rp["losses"]["windows_right"] >= 0.9 * rp["losses"]["windows"] and rp["right_share"] >= 0.85
    # unusable inputs: a message and exit code 2, no traceback
    r = runner.invoke(app, ["evaluate", str(tmp_path / "nope"), "--data", str(w)])
    assert r.exit_code == 2 and "nope" in r.output and "Traceback" not in r.output
    r = runner.invoke(app, ["train", "--data", str(tmp_path / "missing"), "--out", str(tmp_path / "x")])
    assert r.exit_code == 2 and "missing" in r.output


def test_cli_train_on_a_full_disk_names_the_folder_and_leaves_no_manifest(log_dir, tmp_path, monkeypatch):
    """The model folder's writes fail past 2 kB (RLIMIT_FSIZE, EFBIG, SIGXFSZ
    ignored): one ``error:`` line naming the file of the model folder, exit 2, no traceback, and
    no ``manifest.json`` -- never a folder that looks complete."""
    import resource
    import signal

    from terrainml.cli import app
    from terrainml.pipeline import train as train_mod

    from cli_refusal import assert_refused

    real = train_mod.make_factory
    monkeypatch.setattr(train_mod, "make_factory",
                        lambda kind, ds, seed=0, subset="all", n_jobs=1, params=None:
                        real(kind, ds, seed, subset, n_jobs, {**SMALL[kind], **(params or {})}))
    runner = CliRunner()
    w = tmp_path / "w.parquet"
    assert runner.invoke(app, ["dataset", "build", str(log_dir), "--out", str(w), "-q"]).exit_code == 0
    out = tmp_path / "runs" / "svm"
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    old = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (2_000, hard))
    try:
        r = runner.invoke(app, ["train", "--data", str(w), "--model", "svm", "--folds", "3", "--seed", "1",
                                "--out", str(out), "--no-ablation", "-q"])
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
        signal.signal(signal.SIGXFSZ, old)
    assert_refused(r, out, "cannot write")
    assert not (out / "manifest.json").exists() and not list(out.rglob(".*.part"))
