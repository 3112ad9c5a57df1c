"""The serving decision (stream/tick/policy.py): which class a tick serves, the safe cap otherwise,
and the fallback reasons by priority (design §10-11), against hand-worked targets."""

from __future__ import annotations

import numpy as np
import pytest

from terrainml.classes import TERRAIN_CLASSES
from terrainml.lookup.table import DesiredSlipTable
from terrainml.robot import load_robot
from terrainml.stream.tick.policy import NO_CLASS_ID, REASON_PRIORITY, ServingPolicy


class HandTable:
    """Hand-written targets (no ``safe_cap``: the policy takes the cap over the model's classes)."""

    ROWS = {  # id: (traction, braking, steady)
        0: (0.16, -0.16, 0.002), 1: (0.14, -0.18, 0.03), 2: (0.25, -0.30, 0.12),
        3: (0.28, -0.30, 0.13), 4: (0.30, -0.35, 0.19), 5: (0.32, -0.40, 0.20),
        6: (0.40, -0.45, 0.30), 7: (0.50, -0.55, 0.42),
    }

    def target(self, class_id, state):
        tr, br, st = self.ROWS[class_id]
        return {"traction": tr, "braking": br, "steady": st, "idle": 0.0}[state]


class Fused:
    """The fusion filter's face to the policy: a posterior (or None) and a staleness flag."""

    def __init__(self, posterior=None, stale=False, unknown=False):
        self.posterior = None if posterior is None else np.asarray(posterior, dtype=float)
        self.stale = stale
        self.unknown = unknown

    def best(self):
        if self.posterior is None:
            return -1, 0.0
        k = int(np.argmax(self.posterior))
        return k, float(self.posterior[k])


STATES = ["traction", "steady", "braking"]
V_LONG = [1.0, -0.7, 0.4]
POLICY = ServingPolicy(HandTable(), range(8), TERRAIN_CLASSES)


def one_hot(k, p=0.9):
    post = np.full(8, (1 - p) / 7)
    post[k] = p
    return post


def decide(fused, policy=POLICY, **facts):
    kw = {"estimator_ok": True, "classifier_error": False, "age_s": 0.1, **facts}
    return policy.decide(fused, states=STATES, v_long=V_LONG, **kw)


def test_a_confident_fused_class_is_served_with_eq_8_7_signs():
    d = decide(Fused(one_hot(6, 0.7)))
    assert (d.class_id, d.class_name, d.fallback, d.reason) == (6, "dry_sand", False, "")
    assert d.confidence == pytest.approx(0.7)
    assert d.slip_desired == pytest.approx((0.40, -0.30, -0.45))  # dry sand: T, -S, B


def test_at_serve_p_a_class_is_served_below_it_the_safe_cap():
    assert not decide(Fused(one_hot(7, 0.6))).fallback
    d = decide(Fused(one_hot(7, 0.59)))
    assert (d.fallback, d.reason, d.class_id, d.class_name) == (True, "uncertain_classification",
                                                                NO_CLASS_ID, "none")
    # the cap over the 8 classes: largest traction 0.50 (also in steady), braking -0.55
    assert d.slip_desired == pytest.approx((0.50, -0.50, -0.55)) and d.confidence == 0.0


@pytest.mark.parametrize("facts,fused,reason", [
    ({"clock_jump": True, "estimator_ok": False, "classifier_error": True}, Fused(), "clock_jump"),
    ({"estimator_ok": False, "classifier_error": True}, Fused(one_hot(3)), "estimator_unhealthy"),
    ({"classifier_error": True, "rejected_by": "speed"}, Fused(unknown=True), "classifier_error"),
    ({"rejected_by": "speed"}, Fused(one_hot(3, 0.3), stale=True, unknown=True), "unknown_terrain"),
    ({"rejected_by": "speed"}, Fused(), "windows_rejected"),
    ({}, Fused(), "no_classification"),
    ({}, Fused(one_hot(3, 0.3), stale=True), "stale_classification"),
    ({}, Fused(one_hot(3, 0.3)), "uncertain_classification"),
], ids=list(REASON_PRIORITY))
def test_fallback_reasons_by_priority(facts, fused, reason):
    d = decide(fused, **facts)
    assert d.fallback and d.reason == reason and d.class_id == NO_CLASS_ID


def test_rejected_windows_replace_a_stale_class_and_name_the_rule_but_never_a_fresh_one():
    stale = decide(Fused(one_hot(3), stale=True), rejected_by="channel_valid: imu_wx")
    assert (stale.reason, stale.detail) == ("windows_rejected", "channel_valid: imu_wx")
    fresh = decide(Fused(one_hot(3)), rejected_by="speed")  # a fresh class is still served
    assert not fresh.fallback and fresh.detail == ""
    assert decide(Fused(), estimator_ok=False, rejected_by="speed").detail == ""


def test_a_classifier_error_with_a_fused_class_left_still_serves_it():
    d = decide(Fused(one_hot(2)), classifier_error=True)
    assert not d.fallback and d.class_id == 2


def test_an_optional_age_limit_makes_an_old_classification_stale():
    aged = ServingPolicy(HandTable(), range(8), TERRAIN_CLASSES, max_age_s=1.0)
    assert decide(Fused(one_hot(7)), aged, age_s=1.01).reason == "stale_classification"
    assert not decide(Fused(one_hot(7)), aged, age_s=1.0).fallback  # 1.0 s is still fresh
    assert not decide(Fused(one_hot(7)), age_s=1e6).fallback        # off by default


def test_posterior_entries_are_the_classifier_class_ids():
    policy = ServingPolicy(HandTable(), [2, 6], TERRAIN_CLASSES)
    d = decide(Fused([0.2, 0.8]), policy)
    assert (d.class_id, d.class_name) == (6, "dry_sand") and d.confidence == pytest.approx(0.8)
    d = decide(Fused([0.5, 0.5]), policy)  # the cap over classes 2 and 6 only
    assert d.reason == "uncertain_classification"
    assert d.slip_desired == pytest.approx((0.40, -0.40, -0.45))


def test_the_cap_of_a_desired_slip_table_is_taken_over_the_model_classes():
    table = DesiredSlipTable.build(load_robot("agrimaro"))
    ids = [0, 2, 5]
    policy = ServingPolicy(table, ids, table.class_names)
    cap = table.safe_cap([table.class_name(c) for c in ids])
    d = decide(Fused(), policy)
    assert d.slip_desired == pytest.approx((cap.traction, -cap.traction, cap.braking))
    assert policy.safe_cap_traction() == pytest.approx(cap.traction)
    assert cap.traction < table.safe_cap().traction  # wet mud is not one of the model's classes


def test_a_failing_table_serves_zero_slip_and_never_raises():
    class Broken(HandTable):
        def target(self, class_id, state):
            raise KeyError("no such row")

    policy = ServingPolicy(HandTable(), range(8), TERRAIN_CLASSES)
    policy.table = Broken()  # a table that fails after start-up
    d = decide(Fused(one_hot(4)), policy)
    assert d.fallback and d.reason == "classifier_error" and d.slip_desired == (0.0, 0.0, 0.0)


def test_the_priority_orders_every_reason_the_message_names_once():
    from terrainml.stream.tick.message import FALLBACK_REASONS

    assert sorted(REASON_PRIORITY) == sorted(FALLBACK_REASONS)
