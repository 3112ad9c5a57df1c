"""Serving unknown ground: a model that never saw the ground serves the safe cap.

Hand-made truth: a model trained on two slip levels (the ``SLIP_OF`` classes 0 and 2, slip 0.02
and 0.12, simulated kinematic runs) serves one drive whose true slip is 0.02, then 0.45 (far
from both: ground it never saw), then 0.02 again. Where the true slip is 0.45 the ticks must
say ``unknown_terrain`` and serve the class-free safe cap; where it is 0.02 again the class 0
must come back; the same model saved without its novelty entry must serve as before (never
``unknown_terrain``). With ``--record-unknown`` exactly the served ``unknown_terrain`` ticks are
written as one run (rows of the drive itself, inside the far-slip stretch) that, once labelled,
the ingest and ``dataset build`` read like any run.
"""

from __future__ import annotations

import json
import re
import shlex
import subprocess
import sys

import numpy as np
import pytest
from mcap.reader import make_reader
from typer.testing import CliRunner
from stream_fakes import SLIP_OF

from terrainml.classes import TERRAIN_CLASSES
from terrainml.cli import app
from terrainml.io import t265
from terrainml.io.ingest import ingest_to_parquet, load_run
from terrainml.io.mcap_writer import RosMcapWriter
from terrainml.estimation.run import estimate_run
from terrainml.features.sets import FeatureSet
from terrainml.features.windows import Windows, WindowSpec, cut_windows
from terrainml.lookup.table import DesiredSlipTable
from terrainml.models.artifacts import TrainingProvenance, load_artifact, save_artifact
from terrainml.models.novelty import fit_model_novelty
from terrainml.models.svm import SVMClassifier
from terrainml.pipeline.dataset import build_dataset
from terrainml.pipeline.labels import label_run
from terrainml.robot import load_robot
from terrainml.schema import read_run_parquet
from terrainml.stream.tick.config import ServingConfig
from terrainml.stream.tick.fusion import SETTLE_M, FusionConfig, TerrainFilter
from terrainml.stream.tick.predictor import Predictor
from terrainml.stream.tick.sample import Sample
from terrainml.stream.app.recorder import RECORD_FORMATS, UnknownGroundRecorder
from terrainml.stream.transports.ros2.source import STAMP_ORIGIN_KEY
from terrainml.stream.app.runner import serve
from terrainml.stream.transports.sources import iter_table_samples
from terrainml.testing import kinematic_run, trapezoid_speed

ROBOT = load_robot()
KNOWN = (0, 2)
FAR_SLIP = 0.45                          # no trained class slips like this
ON_S, OFF_S, END_S = 20.0, 40.0, 62.0    # the drive: known, unknown from ON_S, known from OFF_S
#: 1 s windows, as the served default (`short`): unknown is entered after U = 5 flagged windows
#: (stream/tick/fusion.unknown_windows_for: window length + 1 s at a 0.5 s hop)
SPEC = WindowSpec(window_s=1.0)


def _train_windows():
    wins = []
    for cid in KNOWN:
        for rep in range(3):
            table = kinematic_run(ROBOT, duration_s=40.0, slip=SLIP_OF[cid], terrain=cid,
                                  seed=500 + 10 * cid + rep, imu_acc_noise=0.005,
                                  vx=lambda t: trapezoid_speed(t, 1.0, 1.0, 1.0), run_id=f"c{cid}r{rep}")
            wins.append(cut_windows(estimate_run(table, ROBOT), ROBOT, spec=SPEC)[0])
    return Windows.concat(wins)


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    """The same SVM saved twice: with its novelty scorer and without (an older folder)."""
    W = _train_windows()
    clf = SVMClassifier(FeatureSet.for_robot(ROBOT), C_grid=[10.0], gamma_grid=["scale"],
                        inner_folds=2).fit(W, W.y)
    scorer, info = fit_model_novelty(clf, W, seed=0)
    out = {}
    for name, nov in (("with", ("svm", scorer, info)), ("without", None)):
        out[name] = tmp_path_factory.mktemp("unknown") / name
        save_artifact(out[name], {"svm": clf}, TrainingProvenance(
                          classes=list(KNOWN), class_names=[TERRAIN_CLASSES[c] for c in KNOWN],
                          channels=list(W.channels), window_spec=SPEC, robot=ROBOT,
                          training_fingerprint="test-unknown"),
                      attachments={"desired_slip_table.json": DesiredSlipTable.build(ROBOT).to_json()},
                      novelty=nov)
    return out


def _slip(t):
    return FAR_SLIP if ON_S <= t < OFF_S else SLIP_OF[0]


@pytest.fixture(scope="module")
def drive():
    table = kinematic_run(ROBOT, duration_s=END_S, slip=_slip, terrain=0, seed=77, imu_acc_noise=0.005,
                          vx=lambda t: trapezoid_speed(t, 1.0, 1.0, 1.0), run_id="drive")
    return table.drop(columns=[c for c in table.columns if c.startswith("gt_") or c in ("terrain", "run_id")])


def _serve(folder, table):
    p = Predictor.from_model_dir(folder)
    out, odo = [], []
    for s in iter_table_samples(table):
        out.append(p.step(s))
        odo.append(p.odometer_m)
    p.close()
    return p, out, np.array(odo)


@pytest.fixture(scope="module")
def served(folders, drive):
    return {name: _serve(folder, drive) for name, folder in folders.items()}


def test_the_folder_loads_its_novelty_scorer_and_the_older_one_has_none(folders):
    with_ = Predictor.from_model_dir(folders["with"])
    assert with_.classifier.novelty is not None and with_.classifier.novelty.threshold > 0
    assert load_artifact(folders["without"]).novelty is None
    assert Predictor.from_model_dir(folders["without"]).classifier.novelty is None


def test_unknown_ground_is_served_the_safe_cap_after_settling_and_the_class_comes_back(served, drive):
    p, out, odo = served["with"]
    t = drive["t_s"].to_numpy()
    reason = np.array([m.fallback_reason for m in out])
    unknown = reason == "unknown_terrain"
    # known ground before: never unknown; the class 0 is served once classified
    assert not unknown[t < ON_S].any()
    assert (np.array([m.terrain_class for m in out])[(t > 10.0) & (t < ON_S)] == 0).mean() > 0.9
    # onto the far slip from known ground: unknown once its flags have lasted SETTLE_M, and the
    # first flagged window comes within one 1 s window (1 m at 1 m/s) of moving onto it; it holds
    # to the end of the stretch
    first = int(np.flatnonzero(unknown)[0])
    assert t[first] >= ON_S
    on_idx = int(np.searchsorted(t, ON_S))
    assert SETTLE_M <= odo[first] - odo[on_idx] <= SETTLE_M + 1.0 + 0.2
    stretch = (t >= t[first]) & (t < OFF_S)
    assert unknown[stretch].mean() > 0.95
    cap = p.safe_cap_traction()
    for m in (out[i] for i in np.flatnonzero(unknown)):
        assert m.fallback and m.terrain_class == -1 and m.terrain_name == "none"
        assert m.novelty > 1.0 or m.t_s >= OFF_S  # known windows confirm the way back after OFF_S
        assert all(s == pytest.approx(cap) for s, st in zip(m.slip_desired, m.wheel_state) if st == "traction")
    # known ground again: the class 0 comes back (after U = 5 known windows, 0.5 s apart), stays
    back = (t >= OFF_S + 4.0)
    assert not unknown[back].any()
    assert (np.array([m.terrain_class for m in out])[back & (t < END_S - 3.0)] == 0).mean() > 0.9
    assert p.stats()["unknown_stretches"] == 1


def test_a_folder_without_novelty_serves_exactly_as_before(served, drive):
    _, old, _ = served["without"]
    _, new, _ = served["with"]
    assert not any(m.fallback_reason == "unknown_terrain" for m in old)
    assert all(m.novelty == -1.0 for m in old)
    # until the first flagged window the two serve the same ticks (only the novelty field differs)
    first = next(i for i, m in enumerate(new) if m.novelty > 1.0)
    for a, b in zip(old[:first], new[:first]):
        da, db = a.to_dict(), b.to_dict()
        for d in (da, db):
            d.pop("novelty"), d.pop("processing_ms")
        assert da == db
    # and on the far slip the closed-set model names a class (today's behaviour)
    t = drive["t_s"].to_numpy()
    far = (t > ON_S + 5.0) & (t < OFF_S)
    assert (np.array([m.terrain_class for m in old])[far] >= 0).mean() > 0.5


def test_closed_set_serving_of_a_folder_with_novelty_equals_the_folder_saved_without_it(folders, drive, served):
    """``ServingConfig(open_set=False)`` (``predict --closed-set``): the score is not used, so the
    folder serves exactly what the same model saved without a novelty entry serves."""
    p = Predictor.from_model_dir(folders["with"], config=ServingConfig(open_set=False))
    assert p.classifier.novelty is None
    closed = [p.step(s) for s in iter_table_samples(drive)]
    p.close()
    _, old, _ = served["without"]
    assert len(closed) == len(old)
    for a, b in zip(old, closed):
        da, db = a.to_dict(), b.to_dict()
        da.pop("processing_ms"), db.pop("processing_ms")
        assert da == db


def test_one_flagged_window_never_leaves_the_class_and_leaving_takes_confirmed_windows():
    f = TerrainFilter(2, confirm_windows=1, unknown_windows=2)
    known, other = np.array([0.9, 0.1]), np.array([0.1, 0.9])
    f.update(known, False, 0.5)
    f.update(known, True, 1.5)  # one over the threshold: still the class
    assert not f.unknown and f.best()[0] == 0 and f.novelty == 1.5
    f.update(known, False, 0.5)
    f.update(known, True, 2.0)
    f.update(known, True, 2.0)
    assert f.unknown
    f.update(other, False, 0.5)  # one known window: still unknown (max(K, U) = 2 are needed)
    assert f.unknown
    f.update(known, False, 0.5)  # names another class than the one before: the count restarts
    assert f.unknown
    f.update(known, False, 0.5)
    assert not f.unknown and f.best()[0] == 0
    g = TerrainFilter(2)
    g.update(known)  # no novelty score: as before
    assert not g.unknown and g.novelty == -1.0


def test_unknown_ground_from_the_start_is_served_unknown_within_u_windows(folders):
    """As on a BorealTC SNOW run: the robot sets off on ground no training run covered. No known
    ground comes before the flags, so U = 5 windows (0.5 s apart, 2 m at 1 m/s) suffice after the
    first classified window, the same tick as without settling."""
    table = kinematic_run(ROBOT, duration_s=12.0, slip=FAR_SLIP, terrain=0, seed=78, imu_acc_noise=0.005,
                          vx=lambda t: trapezoid_speed(t, 1.0, 1.0, 1.0), run_id="far")
    table = table.drop(columns=[c for c in table.columns if c.startswith("gt_") or c in ("terrain", "run_id")])
    first = {}
    for settle_m in (SETTLE_M, 0.0):
        p = Predictor.from_model_dir(folders["with"], config=ServingConfig(fusion=FusionConfig(settle_m=settle_m)))
        out, odo = zip(*((p.step(s), p.odometer_m) for s in iter_table_samples(table)))
        p.close()
        classified = next(i for i, m in enumerate(out) if m.novelty >= 0)
        unknown = next(i for i, m in enumerate(out) if m.fallback_reason == "unknown_terrain")
        assert odo[unknown] - odo[classified] <= 2.0 + 0.05
        first[settle_m] = unknown
    assert first[SETTLE_M] == first[0.0]


def test_flags_after_known_ground_enter_unknown_only_once_they_outlast_the_settling():
    """Hand-worked, 0.25 m between windows: U = 2 flagged windows, settle_m = 1 m."""
    known, flag = np.array([0.9, 0.1]), (np.array([0.9, 0.1]), True, 2.0)
    f = TerrainFilter(2, confirm_windows=1, unknown_windows=2, settle_m=1.0)
    for _ in range(5):  # 1 m of known ground (the first window starts the count at 0 m)
        f.predict(0.25)
        f.update(known, False, 0.5)
    entered = []
    for _ in range(8):
        f.predict(0.25)
        f.update(*flag)
        entered.append(f.unknown)
    # known windows at 0.25-1.25 m, flags from 1.5 m: the stretch has lasted 1 m at its fifth
    # window (2.5 m), not at U = 2
    assert entered == [False, False, False, False, True, True, True, True]
    # after only 0.5 m of known ground, flags are not a change of known terrain: U windows suffice
    g = TerrainFilter(2, confirm_windows=1, unknown_windows=2, settle_m=1.0)
    for _ in range(3):
        g.predict(0.25)
        g.update(known, False, 0.5)
    g.predict(0.25)
    g.update(*flag)
    g.predict(0.25)
    g.update(*flag)
    assert g.unknown
    # settle_m = 0 (the default): U windows, as before
    h = TerrainFilter(2, confirm_windows=1, unknown_windows=2)
    for _ in range(5):
        h.predict(0.25)
        h.update(known, False, 0.5)
    h.update(*flag)
    h.update(*flag)
    assert h.unknown


def test_a_blip_of_flags_shorter_than_a_confirmation_leaves_known_ground_known():
    """Hand-worked, 0.25 m between windows: K = 3, U = 4, settle_m = 1 m. A robot that starts
    again after a stop has a flagged window or two (its drive settling), on ground it knows. Such a
    blip, shorter than the K windows that confirm a class change, does not end the known ground:
    the flags of the next terrain change must still outlast the settling. A stretch of K flags
    does end it, as before."""
    known, flag = np.array([0.9, 0.1]), (np.array([0.9, 0.1]), True, 2.0)

    def entered_after(blip: int) -> list[bool]:
        f = TerrainFilter(2, confirm_windows=3, unknown_windows=4, settle_m=1.0)
        for pattern in ([False] * 8, [True] * blip, [False] * 2):   # 2 m known, a blip, 0.5 m known
            for flagged in pattern:
                f.predict(0.25)
                f.update(*flag) if flagged else f.update(known, False, 0.5)
        assert not f.unknown
        out = []
        for _ in range(6):                                             # the flags of a change
            f.predict(0.25)
            f.update(*flag)
            out.append(f.unknown)
        return out

    # after a blip of 1 or 2 windows: the stretch lasts 1 m at its fifth window
    assert entered_after(1) == entered_after(2) == [False, False, False, False, True, True]
    # after 3 flagged windows, only 0.5 m of known ground: U = 4 windows suffice
    assert entered_after(3) == [False, False, False, True, True, True]


def test_predict_says_unknown_terrain_in_its_json_and_its_summary(folders, drive, tmp_path):
    """``terrainml predict`` end to end (stdin JSON lines in, stdout JSON lines out), recording
    the unknown stretch with ``--record-unknown``."""
    lines = "\n".join(json.dumps(s.columns) for s in iter_table_samples(drive)) + "\n"
    rec = tmp_path / "unknown"
    proc = subprocess.run([sys.executable, "-m", "terrainml.cli", "predict", "--model", str(folders["with"]),
                           "--source", "-", "--sink", "stdout", "--record-unknown", str(rec)], input=lines,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    out = [json.loads(x) for x in proc.stdout.splitlines()]
    unknown = [m for m in out if m["fallback_reason"] == "unknown_terrain"]
    assert unknown and all(ON_S <= m["t_s"] < OFF_S + 4.0 and m["terrain_class"] == -1 for m in unknown)
    assert max(m["novelty"] for m in unknown) > 1.0
    assert "unknown ground: 1 stretch" in proc.stderr
    assert f"recorded unknown ground: 1 run(s) in {rec}" in proc.stderr
    (side,) = [json.loads(p.read_text()) for p in rec.glob("*.json")]
    assert side["t_start_s"] == unknown[0]["t_s"] and side["t_end_s"] == unknown[-1]["t_s"]
    assert side["ticks"] == len(unknown)


def _record(folder, drive, out_dir, origin_ns=None, **kw):
    """Serve the drive with a recorder; (served messages, odometer per tick, recorder). ``origin_ns``:
    every sample carries it as its ROS time origin, as the ROS 2 source's samples do."""
    p = Predictor.from_model_dir(folder)
    rec = UnknownGroundRecorder(out_dir, n_wheels=p.n, class_names=p.class_names, model=str(folder),
                                distance=lambda: p.odometer_m, **kw)
    msgs, odo = [], []

    def keep(m):
        msgs.append(m)
        odo.append(p.odometer_m)

    samples = iter_table_samples(drive)
    if origin_ns is not None:
        samples = (Sample(s.t_s, {**s.columns, STAMP_ORIGIN_KEY: origin_ns}) for s in samples)
    n = serve(p, samples, [rec], on_message=keep)
    rec.close()
    p.close()
    assert n == len(drive)  # the recorder never drops a tick
    return msgs, np.array(odo), rec


def test_record_unknown_writes_exactly_the_unknown_stretch_as_a_run_that_dataset_build_takes(
        folders, drive, tmp_path):
    msgs, odo, rec = _record(folders["with"], drive, tmp_path / "rec")
    served_t = np.array([m.t_s for m in msgs if m.fallback_reason == "unknown_terrain"])
    assert rec.failed == 0 and len(rec.written) == 1
    (path,) = rec.written
    run = read_run_parquet(path)
    # exactly the served unknown ticks, with the drive's own rows (its canonical columns)
    np.testing.assert_array_equal(run["t_s"].to_numpy(), served_t)
    rows = drive.set_index("t_s").loc[served_t]
    for col in ("wheel1_omega_radps", "cam_vx_mps", "imu_ax_mps2"):
        np.testing.assert_array_equal(run[col].to_numpy(), rows[col].to_numpy())
    assert (run["terrain"] == -1).all() and (run["run_id"] == path.stem).all()
    # the truth of the drive: the stretch lies on the far-slip ground (and the windows after it)
    assert served_t[0] >= ON_S and served_t[-1] < OFF_S + 4.0
    assert ((served_t >= ON_S) & (served_t < OFF_S)).mean() > 0.8
    side = json.loads(path.with_suffix(".json").read_text())
    assert (side["t_start_s"], side["t_end_s"], side["ticks"]) == (served_t[0], served_t[-1], len(served_t))
    i0, i1 = (int(np.flatnonzero(np.array([m.t_s for m in msgs]) == t)[0]) for t in (served_t[0], served_t[-1]))
    assert side["distance_m"] == pytest.approx(odo[i1] - odo[i0])
    assert side["distance_m"] == pytest.approx(served_t[-1] - served_t[0], rel=0.2)  # about 1 m/s
    assert side["mean_novelty"] > 1.0 and side["label"] is None and side["model"] == str(folders["with"])
    assert run.attrs["terrainml"]["classes"] == list(Predictor.from_model_dir(folders["with"]).class_names)
    # a person labels it (docs/stream.md "Unknown ground"): then ingest and dataset build take it
    labelled = tmp_path / "labelled" / "far_slip_01.parquet"
    runner = CliRunner()
    r = runner.invoke(app, ["dataset", "label", str(path), "--terrain", "far_slip", "--out", str(labelled)])
    assert r.exit_code == 0, r.output
    classes = run.attrs["terrainml"]["classes"]
    assert "far_slip" not in classes and "a new class" in r.output
    ing = load_run(labelled, robot=ROBOT)
    assert ing.report.usable and len(ing.table) == len(served_t)
    assert (ing.table["terrain"] == len(classes)).all()
    assert json.loads(labelled.with_suffix(".json").read_text())["label"] == "far_slip"
    ds = build_dataset(labelled.parent, ROBOT, spec=SPEC)
    assert len(ds.windows) >= 10 and set(ds.windows.y.tolist()) == {len(classes)}
    assert ds.class_names == ["far_slip"]
    # a known name takes its id; an id outside the run's classes is refused, naming the file
    r = runner.invoke(app, ["dataset", "label", str(path), "-t", classes[0], "-o", str(tmp_path / "k.parquet")])
    assert r.exit_code == 0 and (read_run_parquet(tmp_path / "k.parquet")["terrain"] == 0).all()
    r = runner.invoke(app, ["dataset", "label", str(path), "--terrain", "99"])
    assert r.exit_code == 2 and path.name in r.output and "99" in r.output


@pytest.mark.parametrize("fmt", ["parquet", "mcap"])
def test_a_failed_write_is_counted_and_serving_goes_on(folders, drive, tmp_path, monkeypatch, fmt):
    import terrainml.stream.app.recorder as recorder

    def full_disk(*a, **k):
        raise OSError(28, "No space left on device")

    if fmt == "parquet":
        monkeypatch.setattr(recorder, "write_run_parquet", full_disk)
    else:  # the disk fills in the middle of the MCAP: the writer's own abort must leave nothing
        write_imu = RosMcapWriter.write_imu

        def fills_up(self, *a, **k):  # at the 300th IMU message of each log
            self.n_imu = getattr(self, "n_imu", 0) + 1
            if self.n_imu == 300:
                full_disk()
            return write_imu(self, *a, **k)

        monkeypatch.setattr(RosMcapWriter, "write_imu", fills_up)
    msgs, _, rec = _record(folders["with"], drive, tmp_path / "rec", max_rows=500, fmt=fmt, robot=ROBOT)
    n_unknown = sum(m.fallback_reason == "unknown_terrain" for m in msgs)
    assert n_unknown > 1000  # so the stretch is cut into parts of 500 ticks
    n_parts = -(-n_unknown // 500)
    if fmt == "mcap":  # the last, short part may end before its 300th IMU message: that one is written
        n_parts = n_unknown // 500 + (n_unknown % 500 >= 300)
        assert len(rec.written) == -(-n_unknown // 500) - n_parts
    else:
        assert rec.written == []
    assert rec.failed == n_parts
    assert "No space left on device" in rec.summary() and str(tmp_path / "rec") in rec.errors[0]
    assert len(list((tmp_path / "rec").glob("*.json"))) == len(rec.written)
    assert sorted((tmp_path / "rec").glob(f"*.{fmt}")) == sorted(rec.written)
    assert not list((tmp_path / "rec").glob(".*.part"))  # no partial file left behind


def test_a_record_folder_that_cannot_be_created_is_refused_before_serving(folders, tmp_path, capsys):
    from terrainml.stream.app.options import ServeOptions
    from terrainml.stream.app.runner import run_predict

    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    code = run_predict(ServeOptions(model=folders["with"], source=str(tmp_path / "never_read.parquet"),
                                    sinks=("stdout",), record_unknown=blocker / "unknown"))
    err = capsys.readouterr().err
    assert code == 2 and "--record-unknown" in err and "a_file" in err


def test_recording_with_a_model_without_novelty_warns_that_nothing_will_be_recorded(folders, tmp_path, capsys):
    from terrainml.stream.app.options import ServeOptions
    from terrainml.stream.app.runner import run_predict

    for name, warned in (("without", True), ("with", False)):
        run_predict(ServeOptions(model=folders[name], source=str(tmp_path / "never_read.parquet"),
                                 sinks=("stdout",), record_unknown=tmp_path / name))
        err = capsys.readouterr().err
        assert ("has no novelty scorer" in err) is warned, err


def test_a_second_recording_into_the_same_folder_never_overwrites_the_first(folders, drive, tmp_path, monkeypatch):
    import terrainml.stream.app.recorder as recorder

    epoch = recorder.time.gmtime(0)
    monkeypatch.setattr(recorder.time, "gmtime", lambda *a: epoch)  # both recordings start in the same second
    first = _record(folders["with"], drive, tmp_path / "rec")[2].written
    second = _record(folders["with"], drive, tmp_path / "rec")[2].written
    assert len(first) == len(second) == 1 and first != second
    assert len(list((tmp_path / "rec").glob("*.parquet"))) == len(list((tmp_path / "rec").glob("*.json"))) == 2


def test_record_format_mcap_round_trips_through_ingest_to_the_served_samples(folders, drive, tmp_path):
    """``--record-format mcap``: the stretch as a ROS 2 MCAP that ``terrainml ingest``'s
    ``ingest_to_parquet`` reads back to the drive's own rows (the samples fed in, not the writer's
    output), stamped with the samples' ROS time; the sidecar as for Parquet.

    Tolerances: the writer stamps each row at ``origin + round(t_s * 1e9)`` ns and ingest puts the
    rows on a 100 Hz grid from the first stamp, so grid and samples coincide to 1 ns (the stamp
    rounding: the time bound, 1e-9 s) and resampling moves a value by at most |dv/dt| x 1 ns;
    the fastest of these signals changes by ~0.1 per 10 ms tick (sample noise), 10 units/s, so
    1e-8, and 1e-7 leaves a decade of margin. CDR float64 is exact, and the IMU mount and the
    T265 frame conversion (rotation, lever arm, pose integration) add float rounding only (seen:
    < 1e-15). Ingest zeroes the T265 yaw at its first confident pose (the camera's odom frame
    starts where it boots), so ``cam_yaw_rad`` is compared as the change from the stretch's
    first tick."""
    origin = 1_750_000_000_000_000_000   # a ROS 2 source's time origin (ns)
    msgs, _, rec = _record(folders["with"], drive, tmp_path / "rec", origin_ns=origin, fmt="mcap", robot=ROBOT)
    served_t = np.array([m.t_s for m in msgs if m.fallback_reason == "unknown_terrain"])
    assert rec.failed == 0 and len(rec.written) == 1
    (path,) = rec.written
    assert path.suffix == ".mcap" and not list(path.parent.glob("*.parquet"))
    assert not list(path.parent.glob(".*.part"))
    side = json.loads(path.with_suffix(".json").read_text())
    assert (side["format"], side["run"], side["robot"], side["log_time_origin_ns"]) == \
        ("mcap", path.name, ROBOT.name, origin)
    assert (side["t_start_s"], side["t_end_s"], side["ticks"]) == (served_t[0], served_t[-1], len(served_t))
    with open(path, "rb") as f:   # Foxglove's time line: the samples' ROS time
        reader = make_reader(f)
        stats = reader.get_summary().statistics
        (meta,) = list(reader.iter_metadata())
    assert stats.message_start_time == origin + round(served_t[0] * 1e9)
    assert stats.message_end_time == origin + round(served_t[-1] * 1e9)
    assert json.loads(meta.metadata["classes"]) == list(Predictor.from_model_dir(folders["with"]).class_names)
    assert json.loads(meta.metadata["unknown_ground"])["run_id"] == path.stem
    # ingest, as `terrainml ingest` does, and compare with the drive's rows of the served ticks
    rep = ingest_to_parquet(path, tmp_path / "ingested.parquet", robot=ROBOT)
    assert rep.usable and not rep.errors
    got = read_run_parquet(tmp_path / "ingested.parquet")
    truth = drive.set_index("t_s").loc[served_t].reset_index()
    assert len(got) == len(truth)
    np.testing.assert_allclose(got["t_s"].to_numpy() + side["t_start_s"], served_t, rtol=0, atol=1e-9)
    columns = [c for c in truth.columns if c != "t_s"]
    assert set(columns) <= set(got.columns), set(columns) - set(got.columns)   # nothing lost
    for c in columns:
        want, have = truth[c].to_numpy(), got[c].to_numpy()
        if c.endswith("_valid"):
            np.testing.assert_array_equal(have, want, err_msg=c)
        elif c == "cam_yaw_rad":
            np.testing.assert_allclose(t265.wrap_angle(have - (want - want[0])), 0.0, atol=1e-7, err_msg=c)
        elif c.endswith("yaw_rad"):
            np.testing.assert_allclose(t265.wrap_angle(have - want), 0.0, atol=1e-7, err_msg=c)
        else:
            np.testing.assert_allclose(have, want, rtol=0, atol=1e-7, err_msg=c)
    assert "terrain" not in got or (got["terrain"] == -1).all()   # unlabelled: no /terrain/label messages


def test_an_mcap_run_is_labelled_through_the_ingest_command_the_refusal_names(folders, drive, tmp_path):
    """``dataset label RUN.mcap`` is refused (an MCAP's labels are bare ids of the built-in list)
    with the two commands to run; run as printed, they give a labelled Parquet run with the
    model's classes (from the sidecar) and the sidecar labelled, like a Parquet recording."""
    _, _, rec = _record(folders["with"], drive, tmp_path / "rec", fmt="mcap", robot=ROBOT)
    (path,) = rec.written
    runner = CliRunner()
    r = runner.invoke(app, ["dataset", "label", str(path), "--terrain", "far_slip"])
    out = " ".join(r.output.split())
    assert r.exit_code == 2 and "not a Parquet run table" in out and "terrainml ingest" in out
    assert path.exists() and not path.with_suffix(".parquet").exists()   # nothing written
    with pytest.raises(ValueError) as err:
        label_run(path, "far_slip")
    m = re.search(r"terrainml ingest (.+) && terrainml dataset label (.+)$", str(err.value))
    assert m and f"--robot {ROBOT.name}" in m.group(1)
    r = runner.invoke(app, ["ingest", *shlex.split(m.group(1)), "--quiet"])
    assert r.exit_code == 0, r.output
    r = runner.invoke(app, ["dataset", "label", *shlex.split(m.group(2))])
    assert r.exit_code == 0, r.output
    classes = list(Predictor.from_model_dir(folders["with"]).class_names)
    assert "a new class" in r.output
    run = read_run_parquet(path.with_suffix(".parquet"))
    assert (run["terrain"] == len(classes)).all() and run.attrs["terrainml"]["classes"] == [*classes, "far_slip"]
    side = json.loads(path.with_suffix(".json").read_text())
    assert (side["label"], side["label_id"], side["run"], side["format"]) == \
        ("far_slip", len(classes), path.with_suffix(".parquet").name, "parquet")


def test_an_unknown_record_format_is_refused_before_anything_is_created(folders, tmp_path):
    with pytest.raises(ValueError, match="expected one of parquet, mcap"):
        UnknownGroundRecorder(tmp_path / "a", n_wheels=3, class_names=["x"], model="m", distance=float,
                              fmt="csv")
    with pytest.raises(ValueError, match="needs the robot"):
        UnknownGroundRecorder(tmp_path / "b", n_wheels=3, class_names=["x"], model="m", distance=float, fmt="mcap")
    assert UnknownGroundRecorder(tmp_path / "c", n_wheels=3, class_names=["x"], model="m", distance=float,
                                 fmt=" MCAP ", robot=ROBOT).fmt == "mcap" and RECORD_FORMATS[0] == "parquet"
    r = CliRunner().invoke(app, ["predict", "--model", str(folders["with"]), "--source", str(tmp_path / "none.mcap"),
                                 "--record-unknown", str(tmp_path / "d"), "--record-format", "rosbag"])
    assert r.exit_code == 2 and "--record-format 'rosbag': expected one of parquet, mcap" in " ".join(r.output.split())
    r = CliRunner().invoke(app, ["predict", "--model", str(folders["with"]), "--source", str(tmp_path / "none.mcap"),
                                 "--record-format", "mcap"])
    assert r.exit_code == 2 and "needs --record-unknown" in " ".join(r.output.split())
    assert not any((tmp_path / x).exists() for x in "abd")


def test_predict_settle_m_sets_how_long_flags_after_known_ground_must_last(folders, drive, served):
    """``predict --settle-m 0``: the stretch is entered after its flagged windows alone, earlier than
    with the default (whose ticks the in-process predictor served); a negative value is refused."""
    lines = "\n".join(json.dumps(s.columns) for s in iter_table_samples(drive)) + "\n"
    cmd = [sys.executable, "-m", "terrainml.cli", "predict", "--model", str(folders["with"]), "--source", "-",
           "--sink", "stdout"]
    proc = subprocess.run(cmd + ["--settle-m", "0"], input=lines, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    first_0 = next(json.loads(x)["t_s"] for x in proc.stdout.splitlines()
                   if json.loads(x)["fallback_reason"] == "unknown_terrain")
    _, out, _ = served["with"]
    first_default = next(m.t_s for m in out if m.fallback_reason == "unknown_terrain")
    assert ON_S <= first_0 < first_default
    bad = subprocess.run(cmd + ["--settle-m", "-1"], input="", capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "--settle-m" in bad.stderr
