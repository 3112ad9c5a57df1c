"""The `short` window spec cut online from the ring equals the offline cut, bit for bit;
the serving chain row by row (estimator, ring, the classifier's cut and features) equals the
offline chain; the safe cap is served on fallback, with its reason and no class name."""

from __future__ import annotations

import numpy as np
import pytest
from stream_fakes import FakeClassifier, FakeEstimator, make_samples

from terrainml.estimation.row import EstimatorRow
from terrainml.features.windows import WindowSpec, cut_windows, window_spec
from terrainml.lookup.table import DesiredSlipTable
from terrainml.robot import load_robot
from terrainml.stream.tick.predictor import Predictor
from terrainml.stream.tick.ring import RingBuffer, is_label


@pytest.fixture(scope="module")
def course_est():
    from terrainml.estimation.run import estimate_run
    from terrainml.sim.generate import simulate
    from terrainml.sim.output import run_table

    robot = load_robot()
    res = simulate(None, "course_stop_and_go", speed_mps=0.8, duration_s=25.0, seed=5)
    return robot, estimate_run(run_table(res, "course5"), robot)


def test_short_windows_online_equal_offline_bit_for_bit(course_est):
    robot, est = course_est
    spec = window_spec("short")
    off, counts = cut_windows(est, robot, spec)
    assert counts["n_kept"] >= 5 and counts["n_rejected"] >= 1  # stops give no window
    by_start = {int(s): k for k, s in enumerate(off.meta["start_index"])}
    # online there are no labels: the windows across a transition are kept there too
    unlabelled, _ = cut_windows(est.drop(columns=["terrain", "run_id"]), robot, spec)
    kept_unlabelled = {int(s) for s in unlabelled.meta["start_index"]}
    assert set(by_start) <= kept_unlabelled
    T, hop = spec.n_samples, spec.hop_samples()
    ring = RingBuffer(T)
    matched = 0
    for k, row in enumerate(est.to_dict("records")):
        ring.append(EstimatorRow.from_mapping(row))
        start = k + 1 - T
        if start < 0 or start % hop:
            continue
        snap = ring.snapshot()
        on, c_on = cut_windows(ring.to_columns(snap, is_label), robot, spec, online=True)
        assert len(on) == (1 if start in kept_unlabelled else 0)
        # the serving path reads the snapshot's columns in place (no dict, no DataFrame): same cut
        view = ring.column_view(snap, is_label)
        assert not any(is_label(k) for k in view) and set(view) == set(ring.to_columns(snap, is_label))
        lazy, c_lazy = cut_windows(view, robot, spec, online=True, with_meta=False)
        assert c_lazy == c_on
        np.testing.assert_array_equal(lazy.X, on.X)
        if start in by_start:
            np.testing.assert_array_equal(on.X[0], off.X[by_start[start]])
            matched += 1
    assert matched == len(off)


def test_serving_chain_row_by_row_matches_the_offline_chain_within_1e9():
    """Predictor.step sample by sample (OnlineEstimator -> ring -> WindowClassifier's cut and
    features) gives the features of estimate_run -> cut_windows -> FeatureSet on every offline
    window (the default spec: offline windows every 2 s, the serving hop 0.5 s meets each)."""
    from synthetic_runs import make_run_table

    from terrainml.estimation.online import OnlineEstimator
    from terrainml.estimation.run import estimate_run
    from terrainml.features.sets import FeatureSet
    from terrainml.schema import validate_run_table
    from terrainml.stream.tick.classify import WindowClassifier

    robot = load_robot("agrimaro")
    table = validate_run_table(make_run_table(2, "chain", seed=5, duration_s=10.0))
    spec = WindowSpec()
    off, _ = cut_windows(estimate_run(table, robot), robot, spec)
    assert len(off) >= 3
    fs = FeatureSet.for_robot(robot).fit(off)
    F_off = dict(zip(off.meta["start_index"], fs.transform(off)))
    t0 = float(table["t_s"].iloc[0])
    seen: dict[int, np.ndarray] = {}

    class Uniform:  # the model: every class alike, so serving goes on whatever the window
        classes_ = np.arange(8)

        def predict_proba(self, x):
            self.last = np.asarray(x)[-1]
            return np.full((len(x), 8), 1 / 8)

    class Recording(WindowClassifier):  # the real cut and features; notes what it classified
        def classify_columns(self, columns):
            p = super().classify_columns(columns)
            if p is not None:
                seen[round((float(columns["t_s"][0]) - t0) * spec.rate_hz)] = self.model.last
            return p

    online = OnlineEstimator(robot, "robust", has_imu_yaw=True, has_cam_yaw=True)
    pred = Predictor(robot, DesiredSlipTable.build(robot), Recording(Uniform(), robot, fs, spec),
                     online, window_spec=spec)
    for sample in table.to_dict("records"):
        pred.step(sample)
    assert set(F_off) <= set(seen)
    for start, f in F_off.items():
        np.testing.assert_allclose(seen[start], f, rtol=0, atol=1e-9)
    assert pred.stats()["classifications"] == len(seen) > len(F_off)  # the hop is 0.5 s online


def test_safe_cap_is_served_on_fallback_with_reason_and_no_class():
    """Before any classification the reference table's safe cap is served: traction and steady
    wheels at the largest traction peak of the model's classes, no class named."""
    robot = load_robot()
    table = DesiredSlipTable.build(robot)
    ids = [0, 2, 5, 7]
    names = [table.class_name(c) for c in ids]
    cap = table.safe_cap(names)
    assert cap.traction == pytest.approx(max(table.target(c, "traction") for c in ids))

    class Never(FakeClassifier):
        class_ids = ids
        class_names = table.class_names

        def classify(self, window):
            return None

    pred = Predictor(robot, table, Never(), FakeEstimator(robot))
    out = [pred.step(s) for s in make_samples(robot, 1.0)]
    m = out[-1]
    assert m.fallback and m.fallback_reason == "no_classification"
    assert m.terrain_class == -1 and m.terrain_name == "none" and m.confidence == 0.0
    assert m.wheel_state == ["steady"] * 3
    assert m.slip_desired == pytest.approx([cap.traction] * 3)
    assert m.to_dict()["terrain_name"] == "none"


def test_uncertain_posterior_is_a_fallback():
    robot = load_robot()

    class Flat(FakeClassifier):
        def classify(self, window):
            return np.full(8, 1 / 8)

    pred = Predictor(robot, DesiredSlipTable.build(robot), Flat(), FakeEstimator(robot))
    out = [pred.step(s) for s in make_samples(robot, 3.0)]
    assert out[-1].fallback and out[-1].fallback_reason == "uncertain_classification"
    assert out[-1].terrain_name == "none"


def test_ring_copies_rows_in_column_order_as_the_dict_rows_were():
    """Values by field whatever the layout: a later row without a field gives NaN (None for a
    state), extra fields are not kept, a value that is not a number is NaN."""
    ok = "estimator_ok"
    first = EstimatorRow.from_mapping({"t_s": 0.0, "slip1": 0.1, "state1": "steady", ok: True, "nis_dof": 4})
    later = EstimatorRow.from_mapping({"nis_dof": 3, "t_s": 0.01, ok: False, "extra": 9.0})
    odd = EstimatorRow.from_mapping({"t_s": 0.02, "slip1": "x", "state1": "idle", ok: True, "nis_dof": 10**400})
    ring = RingBuffer(4)
    for r in (first, later, odd):
        ring.append(r)
    frame = ring.frame()
    assert list(frame.columns) == ["t_s", "slip1", "estimator_ok", "nis_dof", "state1"]
    np.testing.assert_array_equal(frame["t_s"], [0.0, 0.01, 0.02])
    np.testing.assert_array_equal(frame["slip1"], [0.1, np.nan, np.nan])
    np.testing.assert_array_equal(frame["nis_dof"], [4.0, 3.0, np.nan])
    assert frame["estimator_ok"].tolist() == [True, False, True]
    assert ring.snapshot()[1][:, 0].tolist() == ["steady", None, "idle"]
