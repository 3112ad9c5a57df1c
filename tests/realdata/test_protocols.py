"""The two BorealTC evaluation protocols: chunking, folds, windows, metrics, features.

Ground truth: the raw CSV files read with plain pandas (durations), the authors' protocol as
written in their paper/code (5-s chunks, stratified folds over chunks), hand-worked signals.
"""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from terrainml.evaluation.cv import CVResult, Scoring, average_results, cross_validate
from terrainml.evaluation.folds import check_groups_not_split
from terrainml.experiments.borealtc import chunk_windows, make_chunks, protocol_folds, windows_per_chunk
from terrainml.features.side_channel import side_channel_features
from terrainml.features.windows import Windows

BOREAL = Path(__file__).resolve().parents[2].parent / "shared" / "datasets" / "borealtc"


# ----------------------------------------------------------------------------- real data
@pytest.mark.acceptance
def test_chunks_follow_raw_durations_and_skip_runs_without_imu(boreal_tables, boreal_windows):
    tables, report = boreal_tables
    chunks, _ = boreal_windows
    assert sorted(report.runs_without("imu")) == ["FLOORING_04", "FLOORING_06", "ICE_01"]
    assert sorted(chunks.runs_without_chunks) == ["FLOORING_04", "FLOORING_06", "ICE_01"]
    per_run = chunks.meta.groupby("run_id").size()
    for cls_dir in sorted(p for p in BOREAL.iterdir() if p.is_dir() and p.name != "published_metrics"):
        for imu in sorted(cls_dir.glob("imu_*.csv")):
            key = imu.stem.split("_", 1)[1]
            ti = pd.read_csv(imu)["time"]
            tp = pd.read_csv(cls_dir / f"pro_{key}.csv")["time"]
            overlap_s = min(ti.max(), tp.max()) - max(ti.min(), tp.min())
            expected = int(np.floor(overlap_s / 5.0 + 1e-6))
            got = int(per_run.get(f"{cls_dir.name}_{key}", 0))
            # the 100 Hz grid may lose the last tick at an exact multiple of 5 s
            assert expected - 1 <= got <= expected, (cls_dir.name, key, overlap_s, got)


@pytest.mark.acceptance
def test_protocol_a_never_splits_a_chunk_but_mixes_runs(boreal_windows):
    _, w = boreal_windows
    folds, chunk_ids = protocol_folds(w, "a", n_splits=5, seed=21)
    chunk = w.meta["chunk_id"].to_numpy()
    assert np.array_equal(chunk_ids, chunk)
    check_groups_not_split(folds, chunk)  # raises if a chunk is in train and test
    test_all = np.concatenate([te for _, te in folds])
    assert np.array_equal(np.sort(test_all), np.arange(len(w)))  # every window tested once
    # the authors' protocol is NOT grouped by run: some run has chunks in train and test
    runs = w.meta["run_id"].to_numpy()
    tr, te = folds[0]
    assert set(runs[tr]) & set(runs[te])
    # stratified over chunks: each fold holds a fifth of every class's chunks (+-1)
    meta = w.meta.drop_duplicates("chunk_id")
    n_class = meta.groupby("terrain").size()
    for _, te in folds:
        got = w.meta.iloc[te].drop_duplicates("chunk_id").groupby("terrain").size()
        assert (np.abs(got - n_class / 5) <= 1).all()


@pytest.mark.acceptance
def test_protocol_b_never_splits_a_run(boreal_windows):
    _, w = boreal_windows
    folds, _ = protocol_folds(w, "b", n_splits=5, seed=0)
    runs = w.meta["run_id"].to_numpy()
    check_groups_not_split(folds, runs)
    assert sum(len(te) for _, te in folds) == len(w)
    for _, te in folds:  # every fold tests every class (ASPHALT has 7 runs for 5 folds)
        assert set(w.meta["terrain"].iloc[te]) == {0, 1, 2, 3, 4}
    with pytest.raises(AssertionError, match="both train and test"):
        check_groups_not_split(protocol_folds(w, "a")[0], runs)


@pytest.mark.acceptance
def test_windows_stay_inside_their_chunk_and_are_homogeneous(boreal_windows):
    chunks, w = boreal_windows
    start = chunks.meta.set_index("chunk_id")["start_index"]
    s = w.meta["start_index"].to_numpy()
    c0 = start.loc[w.meta["chunk_id"]].to_numpy()
    T = w.X.shape[2]
    assert T == 170  # 1.7 s at 100 Hz
    assert ((s >= c0) & (s + T <= c0 + 500)).all()
    counts = w.meta.groupby("terrain").size()
    assert counts.max() / counts.min() < 1.25  # classes balanced like the authors' augmentation
    assert np.isfinite(w.X).all()


# ----------------------------------------------------------------------------- hand-made
def _table(run_id, seconds, terrain, rate=100.0, invalid_at=None):
    n = int(round(seconds * rate))
    t = np.arange(n) / rate
    df = pd.DataFrame({"t_s": t, "terrain": np.full(n, terrain), "run_id": run_id,
                       "imu_valid": True, "wheels_valid": True, "current_valid": True})
    if invalid_at is not None:
        df.loc[invalid_at, "imu_valid"] = False
    for col in ("imu_ax_mps2", "imu_ay_mps2", "imu_az_mps2", "imu_roll_rate_radps",
                "imu_pitch_rate_radps", "imu_yaw_rate_radps", "wheel1_current_a", "wheel2_current_a",
                "wheel1_omega_radps", "wheel2_omega_radps"):
        df[col] = t  # the sample time: lets the test read where a window was cut
    df.attrs["terrainml"] = {"rate_hz": rate}
    return df


def test_chunking_hand_worked():
    # 12.3 s -> chunks [0, 5) and [5, 10); the 2.3-s tail is dropped. Run b: 11 s with a bad IMU
    # sample at 7 s -> its second chunk is dropped and counted.
    tabs = [_table("a", 12.3, 0), _table("b", 11.0, 1, invalid_at=700)]
    ch = make_chunks(tabs, chunk_s=5.0)
    assert ch.meta["start_index"].tolist() == [0, 500, 0]
    assert ch.meta["run_id"].tolist() == ["a", "a", "b"]
    assert ch.dropped["invalid samples"] == 1
    w = chunk_windows(tabs, ch, window_s=1.7, max_windows_per_chunk=3, wheel_radius_m=0.5)
    # class 1 has 1 chunk, class 0 has 2: class 1 gets 3 windows per chunk, class 0 int(3*1/2) = 1
    assert windows_per_chunk(ch.meta["terrain"].to_numpy(), 3) == {0: 1, 1: 3}
    assert len(w) == 2 * 1 + 3
    # class-1 windows start every (500 - 170) // 3 = 110 samples: 0, 1.1, 2.2 s
    b = w.meta["run_id"] == "b"
    assert w.X[b.to_numpy(), 0, 0] == pytest.approx([0.0, 1.1, 2.2])
    # speed channels are omega * R
    k = list(w.channels).index("speed_left_mps")
    assert w.X[0, k, 10] == pytest.approx(0.5 * 0.1)


def test_side_channel_features_hand_worked():
    rate, T = 100.0, 170
    t = np.arange(T) / rate
    track = 0.5708
    names = ["imu_az", "imu_wz", "current_left", "current_right", "speed_left_mps", "speed_right_mps"]
    x = np.stack([9.81 + np.sin(2 * np.pi * 12.0 * t),        # 12 Hz vibration
                  np.full(T, 0.2),                             # turning at 0.2 rad/s
                  np.full(T, 3.0), np.full(T, 5.0),            # currents (A)
                  np.full(T, 0.8), np.full(T, 0.8 + 0.2 * track)])  # kinematically consistent turn
    F, fn = side_channel_features(x[None], names, rate, track_m=track)
    f = dict(zip(fn, F[0]))
    bands = {k: v for k, v in f.items() if k.startswith("imu_az__bp_")}
    assert max(bands, key=bands.get) == "imu_az__bp_10_15hz"
    assert f["imu_az__mean"] == pytest.approx(9.81, abs=0.02)
    assert f["skid__yaw_residual_mean"] == pytest.approx(0.0, abs=1e-9)  # no skid
    v = 0.8 + 0.1 * track
    assert f["current_total__per_speed"] == pytest.approx(8.0 / v)
    assert f["current_lr__diff_mean"] == pytest.approx(-2.0)
    assert f["current_left__per_speed"] == pytest.approx(3.0 / 0.8)
    # roughness invariant: a unit-amplitude sine has std 1/sqrt(2) (170 samples hold an integer
    # number of 12 Hz periods only approximately, hence the tolerance)
    assert f["imu_az__log_std_per_speed2"] == pytest.approx(np.log10(2 ** -0.5 / v ** 2), abs=0.01)
    assert f["current_total__log_abs_per_speed"] == pytest.approx(np.log10(8.0 / v), abs=1e-6)
    # twice the speed, same surface (twice the frequency, same profile): the invariant std / v^2
    # of a profile whose vibration amplitude grows with v^2 stays put
    x_fast = x.copy()
    x_fast[0] = 9.81 + 4.0 * np.sin(2 * np.pi * 24.0 * t)
    x_fast[4:6] *= 2.0
    f_fast = dict(zip(fn, side_channel_features(x_fast[None], names, rate, track_m=track)[0][0]))
    assert f_fast["imu_az__log_std_per_speed2"] == pytest.approx(f["imu_az__log_std_per_speed2"], abs=0.01)
    # a robot that turns at 0.2 rad/s with equal wheel speeds skids: residual 0.2
    x[5] = 0.8
    F2, _ = side_channel_features(x[None], names, rate, track_m=track)
    assert dict(zip(fn, F2[0]))["skid__yaw_residual_mean"] == pytest.approx(0.2)
    assert np.isfinite(F).all()


class _Always:
    """A classifier that always answers the same class (hand-checkable metrics)."""

    def __init__(self, label):
        self.label = label

    def fit(self, X, y, groups=None):
        self.groups_seen_ = groups
        return self

    def predict(self, X):
        return np.full(len(X), self.label)


def test_cross_validate_labels_only_model_recall_and_confusion_hand_worked():
    # 3 classes, 10 windows each; a model that always says class 1 (labels, no probabilities):
    # recall (0, 1, 0), accuracy 1/3
    n = 30
    y = np.repeat([0, 1, 2], 10)
    meta = pd.DataFrame({"run_id": [f"r{k // 5}" for k in range(n)], "terrain": y,
                         "chunk_id": np.arange(n) // 2})
    w = Windows(np.zeros((n, 1, 4)), ("c",), meta)
    folds, runs = protocol_folds(w, "b", n_splits=2, seed=0)
    res = cross_validate(lambda: _Always(1), w, y, runs, folds=folds,
                         scoring=Scoring(class_names=["A", "B", "C"]))
    assert isinstance(res, CVResult) and res.proba is None
    assert res.accuracy == pytest.approx(1 / 3)
    assert res.balanced_accuracy == pytest.approx(1 / 3)
    assert res.recall_per_class() == {"A": 0.0, "B": 1.0, "C": 0.0}
    cm = res.confusion_frame()
    assert cm.loc["A", "B"] == 10 and cm.loc["B", "B"] == 10 and cm.loc["C", "B"] == 10
    assert cm.to_numpy().sum() == n


class _Fixed:
    """A "model" whose probabilities for window k are row k of a fixed table (windows hold k)."""

    def __init__(self, table):
        self.table = table

    def fit(self, X, y, groups=None):
        self.classes_ = np.array([0, 1])
        return self

    def predict_proba(self, X):
        return self.table[np.asarray(X)[:, 0, 0].astype(int)]


def test_average_results_is_the_mean_of_probabilities():
    # two "models" on the same 4 windows, 2 classes: p1 = (0.9, 0.1), (0.4, 0.6), ...; the average
    # of 0.4/0.6 and 0.8/0.2 is 0.6/0.4 -> class 0
    y = np.array([0, 0, 1, 1])
    runs = np.array([0, 0, 1, 1])
    X = np.arange(4.0)[:, None, None]
    folds = [(np.array([2, 3]), np.array([0, 1])), (np.array([0, 1]), np.array([2, 3]))]
    p1 = np.array([[0.9, 0.1], [0.4, 0.6], [0.2, 0.8], [0.6, 0.4]])
    p2 = np.array([[0.8, 0.2], [0.8, 0.2], [0.3, 0.7], [0.7, 0.3]])
    r1, r2 = (cross_validate(lambda p=p: _Fixed(p), X, y, runs, folds=folds,
                             scoring=Scoring(class_names=["a", "b"]))
              for p in (p1, p2))
    assert r1.y_pred.tolist() == [0, 1, 1, 0] and r2.y_pred.tolist() == [0, 0, 1, 0]
    avg = average_results([r1, r2])
    np.testing.assert_allclose(avg.proba[1], [0.6, 0.4])
    assert avg.y_pred.tolist() == [0, 0, 1, 0]
    assert avg.accuracy == pytest.approx(0.75)
    assert avg.recall_per_class() == {"a": 1.0, "b": 0.5}
