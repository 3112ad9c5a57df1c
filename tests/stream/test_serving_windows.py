"""Issue #19: the `short` window spec cut online from the ring equals the offline cut, bit for bit;
the safe cap is served on fallback, with its reason and no class name."""

from __future__ import annotations

import numpy as np
import pytest
from stream_fakes import FakeClassifier, FakeEstimator, make_samples

from terrainml.features.windows import cut_windows, window_spec
from terrainml.lookup.table import DesiredSlipTable
from terrainml.robot import load_robot
from terrainml.stream.predictor import Predictor, RingBuffer, _is_label


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
        ring.append(row)
        start = k + 1 - T
        if start < 0 or start % hop:
            continue
        snap = ring.snapshot()
        on, c_on = cut_windows(ring.to_columns(snap, _is_label), robot, spec, online=True)
        assert len(on) == (1 if start in kept_unlabelled else 0)
        # the serving path reads the snapshot's columns in place (no dict, no DataFrame): same cut
        view = ring.column_view(snap, _is_label)
        assert not any(_is_label(k) for k in view) and set(view) == set(ring.to_columns(snap, _is_label))
        lazy, c_lazy = cut_windows(view, robot, spec, online=True, with_meta=False)
        assert c_lazy == c_on
        np.testing.assert_array_equal(lazy.X, on.X)
        if start in by_start:
            np.testing.assert_array_equal(on.X[0], off.X[by_start[start]])
            matched += 1
    assert matched == len(off)


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

        def classify(self, window):
            return None

    pred = Predictor(robot, table, Never(), FakeEstimator(robot), class_names=table.class_names)
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

