"""Mission suite: pre-registered seeds, deterministic missions, demand ratio by hand, one run."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from terrainml.experiments import missions as ms
from terrainml.experiments.mission_policies import POLICIES
from terrainml.robot import load_robot


def test_seed_sets_fixed_and_disjoint():
    assert ms.EVAL_SEEDS == tuple(range(1000, 1012))
    assert not set(ms.EVAL_SEEDS) & set(ms.TUNING_SEEDS)
    counts = ms.suite_counts()
    assert counts["greenhouse"]["missions"] == 12 * 4 and counts["field"]["missions"] == 12 * 4
    assert {s.seed for s in ms.suite("field")} == set(ms.EVAL_SEEDS)
    assert {s.seed for s in ms.suite("field", "tuning")} == set(ms.TUNING_SEEDS)
    assert len(ms.suite("all")) == 96 and len(ms.suite("greenhouse", limit=3)) == 3


def test_policies_registered():
    assert {"none", "fixed", "terrain-aware", "oracle", "oracle-cap"} <= set(POLICIES)


def test_missions_are_deterministic_and_within_the_issue_ranges():
    for spec in ms.suite("all"):
        a, b = ms.build_mission(spec), ms.build_mission(spec)
        assert a.route == b.route and a.cells == b.cells and a.params == b.params
        legs = a.route.leg_lengths_m
        if spec.family == "greenhouse":
            assert np.all((legs >= 1.0) & (legs <= 2.0)) and a.route.speed_mps == 0.5
            assert all(w.stop_s == 3.0 for w in a.route.waypoints[1:-1])
            assert 0.0 <= a.grade_deg <= 3.0
            assert a.payload_kg[0] == 0.0 and a.payload_kg[-1] == pytest.approx(40.0)
            assert all(np.diff(a.payload_kg) > 0)
        else:
            assert 2.0 <= a.grade_deg <= 8.0 and 0.10 <= a.tool_draft_w <= 0.25
            assert a.patches and all(1.0 <= x1 - x0 <= 3.0 for x0, x1, _ in a.patches)
            assert all(c in (spec.terrain, ms.FIELD_BASE) for c in a.cells)
    starts = [ms.build_mission(s).route.start for s in ms.suite("greenhouse")]
    grades = [ms.build_mission(s).grade_deg for s in ms.suite("greenhouse")]
    assert {"ramp", "step"} == set(starts) and 0.0 in grades and max(grades) > 1.0


def test_open_set_suite_is_every_mission_on_the_held_out_class_as_base_or_patch():
    """By the suite's construction: a greenhouse floor of the class, a greenhouse floor whose
    softer patch class it is (when it has patches), a field route with its patches."""
    for held in ms.OPEN_SET_CLASSES:
        want = set()
        for spec in ms.suite("all"):
            m = ms.build_mission(spec)
            if spec.family == "greenhouse":
                on = spec.terrain == held or (m.params["soft_class"] == held and m.params["n_patches"] > 0)
            else:
                on = spec.terrain == held
            if on:
                want.add(spec)
        got = ms.open_set_suite(held)
        assert set(got) == want and len(got) == len(want) > 24
        assert [s for s in ms.suite("all") if s in want] == got     # the suite's own order
    assert all(s.seed in ms.TUNING_SEEDS for s in ms.open_set_suite("wet_mud", "tuning"))
    with pytest.raises(ValueError, match="unknown class 'snow'"):
        ms.open_set_suite("snow")


def test_demand_ratio_by_hand():
    rb = load_robot()
    m = ms.build_mission(ms.suite("field")[0])
    peaks = {c: 0.5 for c in m.soils}
    th = math.radians(m.grade_deg)
    # no cart: (draft W + W sin theta) / (0.5 W)
    assert ms.demand_ratio(m, rb, peaks) == pytest.approx((m.tool_draft_w + math.sin(th)) / 0.5)
    g = ms.build_mission(ms.suite("greenhouse")[2])      # dry_sand floor
    peaks = {c: 0.2 for c in g.soils}
    th = math.radians(g.grade_deg)
    w = rb.mass_kg * 9.81
    weakest = min(peaks, key=peaks.get)
    cart = (g.cart_mass_kg + 40.0) * 9.81 * (ms.CART_CRR_BY_CLASS[weakest] * math.cos(th) + math.sin(th))
    assert ms.demand_ratio(g, rb, peaks) == pytest.approx((cart + w * math.sin(th)) / (0.2 * w))


def test_run_mission_is_deterministic_for_a_seed():
    spec = min(ms.suite("field"), key=lambda s: ms.build_mission(s).route.nominal_time_s())
    a = ms.run_mission(spec, "none")
    b = ms.run_mission(spec, "none")
    assert json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)   # NaN-safe equality
    for k in ("terrain", "success", "time_s", "distance_m", "energy_j_per_m", "spin_share",
              "max_sinkage_m", "demand_ratio", "family", "seed", "parameters"):
        assert k in a
    assert a["distance_m"] > 0 and np.isfinite(a["energy_j_per_m"])
