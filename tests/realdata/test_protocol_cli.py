"""``terrainml evaluate-protocol`` on a small hand-made BorealTC-layout folder (seconds)."""

import json

import numpy as np
import typer
from typer.testing import CliRunner

from terrainml.commands import borealtc_cmds


def _app():
    app = typer.Typer()

    @app.callback()
    def _root():  # a group, as in terrainml.cli
        pass

    borealtc_cmds.register(app)
    return app


def _write_folder(root, seconds=16.0):
    """Two classes, three runs each. GRAVEL vibrates at 8 Hz with 6 A; TILE at 30 Hz with 3 A."""
    rng = np.random.default_rng(0)
    for cls, f_hz, amps in (("GRAVEL", 8.0, 6.0), ("TILE", 30.0, 3.0)):
        d = root / cls
        d.mkdir(parents=True)
        for run in range(3):
            t = np.arange(0, seconds, 0.01)
            az = 9.81 + np.sin(2 * np.pi * f_hz * t) + 0.1 * rng.standard_normal(t.size)
            imu = "time,wx,wy,wz,ax,ay,az\n" + "\n".join(
                f"{a:.3f},0,0,0,0,0,{z:.4f}" for a, z in zip(t, az))
            (d / f"imu_{run:02d}.csv").write_text(imu)
            tp = np.arange(0, seconds, 0.15)
            cur = amps + 0.2 * rng.standard_normal(tp.size)
            (d / f"pro_{run:02d}.csv").write_text("time,curL,curR,velL,velR\n" + "\n".join(
                f"{a:.3f},{c:.3f},{c:.3f},0.5,0.5" for a, c in zip(tp, cur)))


def test_evaluate_protocol_both_writes_metrics(tmp_path):
    _write_folder(tmp_path / "data")
    out = tmp_path / "r.json"
    res = CliRunner().invoke(_app(), ["evaluate-protocol", str(tmp_path / "data"), "-p", "both",
                                      "-m", "svm", "--quick", "--n-jobs", "1", "--windows-per-chunk", "2",
                                      "--folds", "2", "--json", str(out), "-q"])
    assert res.exit_code == 0, res.output
    d = json.loads(out.read_text())
    assert set(d) == {"a:svm", "b:svm", "_setup"}
    # 6 runs x 3 complete 5-s chunks (16 s) x 2 windows, every window predicted once
    assert d["_setup"]["n_chunks"] == 18 and d["_setup"]["n_windows"] == 36
    for k in ("a:svm", "b:svm"):
        assert np.asarray(d[k]["confusion_matrix"]).sum() == 36
        assert d[k]["classes"] == ["GRAVEL", "TILE"]
        assert d[k]["accuracy"] > 0.9  # the two terrains differ plainly (8 vs 30 Hz, 6 vs 3 A)


def test_bad_input_exits_2_and_names_it(tmp_path):
    res = CliRunner().invoke(_app(), ["evaluate-protocol", str(tmp_path / "nope")])
    assert res.exit_code == 2 and "nope" in res.output and "Traceback" not in res.output
    res = CliRunner().invoke(_app(), ["evaluate-protocol", str(tmp_path), "-p", "c"])
    assert res.exit_code == 2 and "--protocol" in res.output


def test_trees_and_probability_average_on_plain_terrains(tmp_path):
    """``-m hgb,svm+hgb``: the boosted trees and the fixed-rule average each predict every window,
    and both separate two plainly different terrains under the grouped-by-run protocol."""
    _write_folder(tmp_path / "data")
    out = tmp_path / "r.json"
    res = CliRunner().invoke(_app(), ["evaluate-protocol", str(tmp_path / "data"), "-p", "b",
                                      "-m", "hgb,svm+hgb", "--quick", "--n-jobs", "1", "--windows-per-chunk", "2",
                                      "--folds", "2", "--json", str(out), "-q"])
    assert res.exit_code == 0, res.output
    d = json.loads(out.read_text())
    assert set(d) == {"b:hgb", "b:svm+hgb", "_setup"}
    for k in ("b:hgb", "b:svm+hgb"):
        assert np.asarray(d[k]["confusion_matrix"]).sum() == 36
        assert d[k]["balanced_accuracy"] > 0.9


def test_unknown_model_in_an_average_is_refused(tmp_path):
    _write_folder(tmp_path / "data")
    res = CliRunner().invoke(_app(), ["evaluate-protocol", str(tmp_path / "data"), "-m", "svm+forest"])
    assert res.exit_code == 2 and "svm+forest" in res.output
