"""Per-wheel sign logic of the served targets (design §10, thesis eq. 8.7-8.9, Table 8.1).

Which targets a tick serves (a class or the safe cap, and why) is tested on the serving path:
``tests/stream/test_serving_policy.py``."""

from __future__ import annotations

import math

import pytest

from terrainml.lookup.wheel_targets import desired_slip_per_wheel, safe_cap_per_wheel


class HandTable:
    """A hand-written table: rows ordered so pavement is NOT the first by magnitude on every
    column, to catch a policy that simply picks id 0."""

    ROWS = {  # id: (name, traction, braking, steady)
        0: ("pavement", 0.16, -0.16, 0.002),
        1: ("compacted_dirt", 0.14, -0.18, 0.03),
        2: ("short_grass", 0.25, -0.30, 0.12),
        3: ("gravel_on_firm_soil", 0.28, -0.30, 0.13),
        4: ("tall_damp_grass", 0.30, -0.35, 0.19),
        5: ("tilled_loam", 0.32, -0.40, 0.20),
        6: ("dry_sand", 0.40, -0.45, 0.30),
        7: ("wet_mud", 0.50, -0.55, 0.42),
    }
    class_ids = tuple(ROWS)

    def class_name(self, cid: int) -> str:
        return self.ROWS[cid][0]

    def target(self, class_id: int, state: str) -> float:
        name, tr, br, st = self.ROWS[class_id]
        return {"traction": tr, "braking": br, "steady": st, "idle": 0.0}[state]


TABLE = HandTable()


# ---------------------------------------------------------------- sign logic (eq. 8.7-8.9)
# thesis Table 8.1: (case, v_long [m/s], manoeuvre, sign of the desired slip)
TABLE_8_1_SIGNS = [("1A", +0.6, "traction", +1), ("1B", +0.6, "traction", +1),
                   ("1C", +0.5, "braking", -1), ("1D", +0.5, "braking", -1),
                   ("2A", -0.6, "traction", -1), ("2B", -0.6, "traction", -1),
                   ("2C", -0.5, "braking", +1), ("2D", -0.5, "braking", +1)]


@pytest.mark.parametrize("case,v,state,sign", TABLE_8_1_SIGNS, ids=[c[0] for c in TABLE_8_1_SIGNS])
def test_served_sign_matches_thesis_table_8_1(case, v, state, sign):
    for cid in TABLE.class_ids:
        s = desired_slip_per_wheel(cid, [state], [v], TABLE)[0]
        assert math.copysign(1.0, s) == sign and abs(s) == abs(TABLE.target(cid, state))


def test_idle_and_zero_speed_wheels_get_zero_and_steady_follows_direction():
    s = desired_slip_per_wheel(4, ["idle", "steady", "steady", "traction", "braking"],
                               [1.0, 0.5, -0.5, 0.0, float("nan")], TABLE)
    assert s == [0.0, 0.19, -0.19, 0.0, 0.0]


def test_unknown_state_and_length_mismatch_are_rejected():
    with pytest.raises(ValueError, match="unknown wheel state"):
        desired_slip_per_wheel(0, ["cruise"], [1.0], TABLE)
    with pytest.raises(ValueError, match="length"):
        desired_slip_per_wheel(0, ["steady"], [1.0, 2.0], TABLE)


class HandCap:
    """A safe cap by hand: traction 0.5 (served in traction and steady), braking -0.55."""

    def safe_cap(self, classes=None):
        return self

    def target(self, state):
        return {"traction": 0.5, "steady": 0.5, "braking": -0.55, "idle": 0.0}[state]


def test_safe_cap_per_wheel_follows_the_same_sign_logic():
    s = safe_cap_per_wheel(["traction", "steady", "braking", "braking", "idle", "steady"],
                           [1.0, -0.7, 0.4, -0.4, 1.0, 0.0], HandCap())
    assert s == [0.5, -0.5, -0.55, 0.55, 0.0, 0.0]
