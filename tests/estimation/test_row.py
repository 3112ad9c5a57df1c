"""The estimator (EST) row: typed, immutable, read by name, per wheel and in column order."""

from __future__ import annotations

import math

import pytest

from terrainml.estimation.online import OnlineEstimator, est_state_columns
from terrainml.estimation.row import EstimatorRow, RowLayout
from terrainml.robot import load_robot
from terrainml.schema import EST_OK, EST_WHEEL_KINDS, est_columns, est_wheel_col
from terrainml.testing import kinematic_run


def test_online_step_makes_an_immutable_row_in_the_est_tables_column_order():
    robot = load_robot("agrimaro")
    table = kinematic_run(robot, duration_s=1.0, slip=0.1, seed=3)
    est = OnlineEstimator(robot, "robust")
    rows = [est.step(rec) for rec in table.to_dict("records")]
    row = rows[-1]
    assert type(row) is EstimatorRow
    n = robot.n_wheels
    assert list(row)[:len(est_columns(n))] == est_state_columns(n) == est_columns(n)
    assert len({id(r.layout) for r in rows}) == 1          # one layout for one key layout
    assert row.t_s == row["t_s"] == table["t_s"].iloc[-1]
    assert row.estimator_ok is row[EST_OK]
    for kind in EST_WHEEL_KINDS:
        assert list(row.wheels(kind, n)) == [row[est_wheel_col(kind, i)] for i in range(1, n + 1)]
    assert row["gt_slip1"] == table["gt_slip1"].iloc[-1]    # truth is passed through
    with pytest.raises(AttributeError):
        row.values = ()
    with pytest.raises(TypeError):
        row["slip1"] = 0.0  # type: ignore[index]
    assert list(est.row()) == est_columns(n)


def test_a_new_row_for_a_flag_or_more_columns_leaves_the_old_one_as_it_was():
    row = EstimatorRow.from_mapping({"t_s": 1.0, "slip1": 0.2, EST_OK: True})
    off = row.with_flag(False)
    assert row.estimator_ok and not off.estimator_ok and off.layout is row.layout
    assert dict(off) == {"t_s": 1.0, "slip1": 0.2, EST_OK: False}
    plus = row.with_columns(("imu_roll_rate_radps",), (0.5,))
    assert list(plus) == ["t_s", "slip1", EST_OK, "imu_roll_rate_radps"] and "imu_roll_rate_radps" not in row
    assert plus.layout is row.with_columns(("imu_roll_rate_radps",), (0.7,)).layout  # cached
    bare = EstimatorRow.from_mapping({"t_s": 2.0})
    assert bare.estimator_ok and list(bare.with_flag(False)) == ["t_s", EST_OK]   # no flag: True, added
    assert bare.wheels("slip", 1) is None and math.isnan(EstimatorRow.from_mapping({}).t_s)
    assert EstimatorRow.from_mapping(row) is row
    with pytest.raises(ValueError):
        RowLayout(("t_s", "t_s"))

