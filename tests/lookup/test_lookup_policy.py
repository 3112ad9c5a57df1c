"""Serving policy and per-wheel sign logic (design §10, thesis eq. 8.7-8.9, Table 8.1)."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from terrainml.lookup.policy import choose, desired_slip_per_wheel, fallback_class_id


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
STATES = ["traction", "steady", "braking"]
V_LONG = [1.0, -0.7, 0.4]


def probs(**kw: float) -> np.ndarray:
    p = np.zeros(8)
    for k, v in kw.items():
        p[int(k[1:])] = v
    return p


def test_confident_classification_serves_the_argmax_class():
    d = choose(probs(c6=0.7, c5=0.2, c7=0.1), age_s=0.3, estimator_ok=True, table=TABLE,
               states=STATES, v_long=V_LONG)
    assert (d.class_id, d.class_name, d.fallback, d.reason) == (6, "dry_sand", False, "")
    assert d.confidence == pytest.approx(0.7)
    assert d.slip_desired == pytest.approx((0.40, -0.30, -0.45))


def test_exactly_at_confidence_threshold_is_confident():
    d = choose(probs(c7=0.6, c2=0.4), 0.0, True, TABLE)
    assert d.class_id == 7 and not d.fallback


def test_uncertain_two_close_classes_serve_the_less_aggressive_one():
    d = choose(probs(c6=0.45, c5=0.40, c0=0.15), 0.2, True, TABLE, states=STATES,
               v_long=V_LONG)
    # candidates with p >= 0.1: 6, 5, 0 -> smallest traction magnitude is pavement (0.16)
    assert d.class_id == 0 and not d.fallback and d.reason == ""
    assert d.confidence == pytest.approx(0.15)
    d = choose(probs(c6=0.45, c5=0.40, c0=0.09, c1=0.06), 0.2, True, TABLE, states=STATES,
               v_long=V_LONG)
    # pavement (0.09) and dirt (0.06) are below 0.1: the less aggressive of 5 and 6 is 5
    assert (d.class_id, d.class_name) == (5, "tilled_loam")
    assert d.slip_desired == pytest.approx((0.32, -0.20, -0.40))


def test_uncertain_dirt_beats_pavement_on_traction_magnitude():
    d = choose(probs(c0=0.5, c1=0.5), 0.2, True, TABLE)
    assert d.class_id == 1  # 0.14 < 0.16: least aggressive is not "always pavement"


def test_flat_distribution_with_no_candidate_falls_back_to_argmax():
    p = np.full(8, 1 / 8) * 0.72
    p[3] += 0.28  # 0.37 on class 3, 0.09 elsewhere
    d = choose(p, 0.2, True, TABLE)
    assert d.class_id == 3 and not d.fallback


def test_stale_classification_falls_back_to_pavement():
    d = choose(probs(c7=0.99), age_s=1.01, estimator_ok=True, table=TABLE, states=STATES,
               v_long=V_LONG)
    assert (d.class_id, d.class_name, d.fallback, d.reason) == (0, "pavement", True,
                                                                "stale_classification")
    assert d.confidence == 0.0
    assert d.slip_desired == pytest.approx((0.16, -0.002, -0.16))
    assert not choose(probs(c7=0.99), 1.0, True, TABLE).fallback  # 1.0 s is still fresh


@pytest.mark.parametrize("p,age", [(None, None), (np.array([]), None), (probs(c2=1.0), None),
                                   (np.full(8, np.nan), 0.1)])
def test_no_classification_yet_falls_back(p, age):
    d = choose(p, age, True, TABLE, states=STATES, v_long=V_LONG)
    assert (d.class_id, d.fallback, d.reason) == (0, True, "no_classification")


def test_estimator_unhealthy_falls_back_even_with_a_fresh_confident_class():
    d = choose(probs(c7=1.0), 0.0, False, TABLE, states=STATES, v_long=V_LONG)
    assert (d.class_id, d.class_name, d.fallback, d.reason) == (0, "pavement", True,
                                                                "estimator_unhealthy")
    d = choose(None, None, False, TABLE)
    assert d.reason == "estimator_unhealthy"  # health is reported first


def test_fallback_row_is_pavement_not_simply_the_least_aggressive():
    assert fallback_class_id(TABLE) == 0


def test_class_ids_map_probability_entries():
    d = choose([0.2, 0.8], 0.1, True, TABLE, class_ids=[2, 6])
    assert d.class_id == 6 and d.confidence == pytest.approx(0.8)


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


def test_choose_is_cheap_enough_for_a_10ms_tick():
    p = probs(c6=0.45, c5=0.40, c0=0.15)
    n = 2000
    t0 = time.perf_counter()
    for _ in range(n):
        choose(p, 0.2, True, TABLE, states=STATES, v_long=V_LONG)
    per_call_ms = (time.perf_counter() - t0) / n * 1e3
    assert per_call_ms < 0.2  # generous bound on a slow CI core; typical is ~0.02 ms
