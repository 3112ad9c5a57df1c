"""BorealTC with one class cut to a single run: ``terrainml train`` trains, saves and serves it,
and the report names the rule applied to that class (grouped CV cannot score a class on an
unseen run when it has one run).

The fast test takes a few runs per class and the fixed path (`--windows chunks --model svm`,
small folds, short replay); the acceptance test runs the default `train` on the whole dataset.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from conftest import BOREAL

#: the class cut to its first run
SINGLE = "FLOORING"


def _cut(dest: Path, runs_per_class: int | None) -> Path:
    """A BorealTC folder of symbolic links: SINGLE with its run 00 only, the others with their
    first ``runs_per_class`` runs (None: all)."""
    if not BOREAL.is_dir():
        pytest.skip(f"real dataset not present at {BOREAL}")
    for cls in sorted(p for p in BOREAL.iterdir() if p.is_dir()):
        ids = sorted({f.stem.split("_")[1] for f in cls.glob("pro_*.csv")})
        keep = ids[:1] if cls.name == SINGLE else (ids if runs_per_class is None else ids[:runs_per_class])
        (dest / cls.name).mkdir(parents=True)
        for i in keep:
            for kind in ("pro", "imu"):
                src = cls / f"{kind}_{i}.csv"
                if src.exists():
                    (dest / cls.name / src.name).symlink_to(src)
    return dest


def _check_saved_and_served(out: Path) -> dict:
    from terrainml.stream.tick.classify import load_serving_model

    rep = json.loads((out / "report.json").read_text())
    assert [e["class"] for e in rep["excluded_classes"]] == [SINGLE]
    assert "trained on, not scored" in rep["preflight"]["rules"][SINGLE]
    assert f"`{SINGLE}`: 1 run: trained on, not scored" in (out / "report.md").read_text()
    manifest = json.loads((out / "manifest.json").read_text())
    assert SINGLE in manifest["class_names"]
    served = load_serving_model(out)  # verified, with its members, as `predict` opens it
    assert SINGLE in served.class_names
    return rep


def test_fast_a_single_run_class_trains_saves_and_serves(tmp_path, monkeypatch):
    import terrainml.pipeline.train as train_lib
    from terrainml.cli import app

    real = train_lib.make_factory  # one point of the SVM grid: the test is about the data, not accuracy
    monkeypatch.setattr(train_lib, "make_factory", lambda kind, ds, seed=0, subset="all", n_jobs=1, params=None:
                        real(kind, ds, seed, subset, n_jobs, {"C_grid": (10.0,), "gamma_grid": ("scale",),
                                                              **(params or {})}))

    data = _cut(tmp_path / "boreal", runs_per_class=3)
    out = tmp_path / "m"
    r = CliRunner().invoke(app, ["train", "--data", str(data), "--format", "borealtc", "--windows", "chunks",
                                 "--model", "svm", "--folds", "2", "--replay-s", "5", "--no-ablation",
                                 "--no-members", "--out", str(out), "-q"])
    assert r.exit_code == 0, r.output
    rep = _check_saved_and_served(out)
    assert rep["replay"]["folds"] and rep["replay"]["refusal"] == ""


@pytest.mark.acceptance
def test_default_train_on_borealtc_with_a_single_run_class_trains_saves_and_serves(tmp_path):
    from terrainml.cli import app

    data = _cut(tmp_path / "boreal", runs_per_class=None)
    out = tmp_path / "m"
    # the default train (every candidate, nested CV, served replay, members) at 3 outer folds
    # instead of 5: about half the fits, so it fits CI's hour next to the rest of the tier
    r = CliRunner().invoke(app, ["train", "--data", str(data), "--format", "borealtc", "--folds", "3",
                                 "--out", str(out), "-q"])
    assert r.exit_code == 0, r.output
    rep = _check_saved_and_served(out)
    assert rep["replay"]["pooled"]["moving_ticks"] > 0 and rep["replay"]["refusal"] == ""
