"""Desired-slip table (design §10): rules, physics of each target, robot dependence, JSON.

Independent truth: the terramechanics force curves themselves (evaluated here on a finer grid
than the table's), the analytic Burckhardt peak s* = ln(c1 c2 / c3) / c2 (design §6.2: 0.16 on
dry concrete), ``terramechanics.steady_slip`` (its own root finder), and thesis Table 8.1.
"""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from terrainml.classes import TERRAIN_CLASSES
from terrainml.lookup import terramechanics as tm
from terrainml.lookup.wheel_targets import desired_slip_per_wheel
from terrainml.lookup.table import DesiredSlipTable, LookupTableError
from terrainml.robot import load_robot

CLASS_IDS = list(range(len(TERRAIN_CLASSES)))
RIGID = ("pavement", "compacted_dirt")


@pytest.fixture(scope="module")
def robot():
    return load_robot()


@pytest.fixture(scope="module")
def table(robot):
    return DesiredSlipTable.build(robot)


@pytest.fixture(scope="module")
def heavy_table(robot):
    return DesiredSlipTable.build(dataclasses.replace(robot, mass_kg=robot.mass_kg * 1.5))


@pytest.fixture(scope="module")
def husky_table():
    return DesiredSlipTable.build(load_robot("husky"))


def mu_net(cid, robot, s):
    """Independent vehicle curve: equal-slip, load-weighted over the robot's static loads."""
    p = tm.nominal_params(cid)
    loads = robot.static_wheel_loads_n()
    num = sum(w * tm.net_traction_coefficient(p, w, s, robot) for w in loads)
    return num / sum(loads)


# ---------------------------------------------------------------- design §10 rules, per class
@pytest.mark.parametrize("which", ["agrimaro", "husky"])
@pytest.mark.parametrize("cid", CLASS_IDS, ids=TERRAIN_CLASSES)
def test_rules_hold_for_every_class(cid, which, table, husky_table):
    t = table if which == "agrimaro" else husky_table
    name = TERRAIN_CLASSES[cid]
    s_t, s_b, s_s = (t.target(cid, st) for st in ("traction", "braking", "steady"))
    assert s_t >= s_s + 0.03 - 1e-9, "traction must exceed cruise slip by 0.03"
    assert max(abs(s_t), abs(s_b), abs(s_s)) <= 0.6 + 1e-12, "no target beyond 0.6"
    if name in RIGID:
        assert 0.10 <= s_t <= 0.20, "rigid-surface traction peak in 0.10-0.20"
    assert s_t > 0 and s_b < 0 and s_s >= 0
    assert t.target(cid, "idle") == 0.0


def test_rule_violations_by_the_physics_are_clamped_and_recorded(robot):
    soft_concrete = dataclasses.replace(tm.nominal_params(0), c2=5.0, c3=0.3)  # peak s* ~ 0.6
    t = DesiredSlipTable.build(robot, class_ids=[0], params={0: soft_concrete})
    row = t.row(0)
    assert row.traction == pytest.approx(0.20)
    assert any("outside [0.1, 0.2]" in n for n in row.notes)
    assert t.check_rules() == []
    # a slowly saturating curve (knee at s ~ 0.68) on a non-rigid class: magnitudes clamped
    slow = dataclasses.replace(tm.nominal_params(0), class_id=7, name="wet_mud", c2=1.0, c3=0.0)
    t = DesiredSlipTable.build(robot, class_ids=[7], params={7: slow})
    row = t.row(7)
    assert (row.traction, row.braking) == (pytest.approx(0.6), pytest.approx(-0.6))
    assert sum("beyond |0.6|" in n for n in row.notes) == 2
    assert t.check_rules() == []


# ---------------------------------------------------------------- each target is what it claims
def test_pavement_traction_is_the_burckhardt_peak(table):
    p = tm.nominal_params(0)
    s_star = math.log(p.c1 * p.c2 / p.c3) / p.c2  # 0.159 for dry concrete
    assert table.target(0, "traction") == pytest.approx(s_star, abs=0.002)
    assert table.target(0, "braking") == pytest.approx(-s_star, abs=0.002)  # symmetric curve
    assert table.row(0).traction_kind == "peak"


@pytest.mark.parametrize("cid", CLASS_IDS, ids=TERRAIN_CLASSES)
def test_steady_target_balances_thrust_and_resistance(cid, table, robot):
    row = table.row(cid)
    if any("steady" in n for n in row.notes):
        pytest.skip(f"steady adjusted by a rule: {row.notes}")
    s_s = row.steady
    p = tm.nominal_params(cid)
    w = robot.static_wheel_loads_n()[0]  # reference robot: equal loads
    assert s_s == pytest.approx(tm.steady_slip(p, w, robot), abs=1e-3)
    assert abs(mu_net(cid, robot, np.array([s_s]))[0]) < 5e-3
    below = mu_net(cid, robot, np.linspace(0.0, max(s_s - 0.002, 0.0), 50))
    assert np.all(below <= 1e-6), "steady must be the smallest slip that keeps speed"


@pytest.mark.parametrize("cid", CLASS_IDS, ids=TERRAIN_CLASSES)
def test_traction_and_braking_targets_sit_at_peak_or_knee(cid, table, robot):
    row = table.row(cid)
    for branch, s_target, kind, sign in (("traction", row.traction, row.traction_kind, 1.0),
                                         ("braking", row.braking, row.braking_kind, -1.0)):
        if any(branch in n and ("clamped" in n or "raised" in n) for n in row.notes):
            continue  # value set by a rule, checked by the rule tests
        s = sign * np.linspace(0.0005, 0.8, 4000)
        y = sign * mu_net(cid, robot, s)
        y_t = sign * mu_net(cid, robot, np.array([s_target]))[0]
        if kind == "peak":
            assert y_t >= y.max() - 2e-3, f"{branch}: not at the peak"
            assert y[-1] < y.max(), f"{branch}: a 'peak' at the end of the range"
        else:
            level = 0.9 * y.max()
            assert y_t >= level - 2e-3, f"{branch}: knee below 90 % of max"
            assert np.all(y[np.abs(s) < abs(s_target) - 0.003] < level), f"{branch}: not first"


def test_braking_is_at_least_as_aggressive_as_traction_on_soft_soils(table):
    # thesis §8.3.2: the braking target "naturally features a higher absolute value"
    for cid in (5, 6):
        assert abs(table.target(cid, "braking")) >= table.target(cid, "traction")


# ---------------------------------------------------------------- robot dependence
def test_heavier_robot_sinks_more_and_needs_more_steady_slip_on_deformable_soil(
        table, heavy_table, robot):
    heavy = dataclasses.replace(robot, mass_kg=robot.mass_kg * 1.5)
    for cid in CLASS_IDS:
        p = tm.nominal_params(cid)
        if not p.is_bekker:
            continue
        w, w_h = robot.static_wheel_loads_n()[0], heavy.static_wheel_loads_n()[0]
        assert tm.static_sinkage_m(p, w_h, heavy) > tm.static_sinkage_m(p, w, robot)
        assert heavy_table.target(cid, "steady") > table.target(cid, "steady") + 1e-3, \
            TERRAIN_CLASSES[cid]
        assert heavy_table.row(cid).mu_net_traction_max < table.row(cid).mu_net_traction_max
    # a rigid surface's friction coefficient does not depend on load: pavement unchanged
    for st in ("traction", "braking", "steady"):
        assert heavy_table.target(0, st) == pytest.approx(table.target(0, st), abs=1e-6)


def test_table_records_the_robot_it_was_built_for(table, husky_table, robot):
    assert table.robot_sha256 == robot.sha256()
    assert husky_table.robot_sha256 == load_robot("husky").sha256()
    assert len(husky_table.wheel_loads_n) == 4


def test_centre_of_mass_outside_support_is_refused(robot):
    bad = dataclasses.replace(robot, com_x_m=3.0)
    with pytest.raises(LookupTableError, match="centre of mass"):
        DesiredSlipTable.build(bad)


# ---------------------------------------------------------------- lookup interface
def test_target_lookup_errors(table):
    with pytest.raises(ValueError, match="unknown wheel state"):
        table.target(0, "cruise")
    with pytest.raises(LookupTableError, match="class id 9"):
        table.target(9, "steady")


TABLE_8_1 = [("1A", +0.6, "traction", +1), ("1B", +0.6, "traction", +1),
             ("1C", +0.5, "braking", -1), ("1D", +0.5, "braking", -1),
             ("2A", -0.6, "traction", -1), ("2B", -0.6, "traction", -1),
             ("2C", -0.5, "braking", +1), ("2D", -0.5, "braking", +1)]


@pytest.mark.parametrize("cid", CLASS_IDS, ids=TERRAIN_CLASSES)
def test_served_sign_for_thesis_table_8_1_cases(cid, table):
    states = [c[2] for c in TABLE_8_1]
    v = [c[1] for c in TABLE_8_1]
    slip = desired_slip_per_wheel(cid, states, v, table)
    assert [int(math.copysign(1, s)) for s in slip] == [c[3] for c in TABLE_8_1]
    assert [abs(s) for s in slip] == [abs(table.target(cid, st)) for st in states]


# ---------------------------------------------------------------- serialisation
def test_json_round_trip_keeps_targets_params_and_robot(table, robot):
    text = table.to_json()
    doc = json.loads(text)
    assert doc["robot"]["sha256"] == robot.sha256()
    assert doc["classes"][6]["params"]["k_phi"] == pytest.approx(tm.nominal_params(6).k_phi)
    back = DesiredSlipTable.from_json(text, robot=robot)
    for cid in CLASS_IDS:
        for st in ("traction", "braking", "steady", "idle"):
            assert back.target(cid, st) == table.target(cid, st)
    assert back.robot_sha256 == table.robot_sha256


def test_summary_json_shape(table):
    summary = table.to_summary()
    assert list(summary) == ["classes"]
    assert [c["id"] for c in summary["classes"]] == CLASS_IDS
    assert set(summary["classes"][0]) == {"id", "name", "traction", "braking", "steady"}
    assert summary["classes"][0]["name"] == "pavement"


def test_from_json_refuses_tampered_wrong_robot_and_broken_tables(table, robot):
    doc = json.loads(table.to_json())
    doc["classes"][2]["traction"] = 0.05
    with pytest.raises(LookupTableError, match="checksum"):
        DesiredSlipTable.from_json(json.dumps(doc))
    with pytest.raises(LookupTableError, match="not for 'husky'"):
        DesiredSlipTable.from_json(table.to_json(), robot=load_robot("husky"))
    # robot spec edited and checksum recomputed: the spec hash no longer matches
    from terrainml.lookup.table import _checksum

    doc = json.loads(table.to_json())
    doc["robot"]["spec"]["mass_kg"] = 120.0
    doc["checksum_sha256"] = _checksum(doc)
    with pytest.raises(LookupTableError, match="robot spec sha256"):
        DesiredSlipTable.from_json(json.dumps(doc))
    # a consistently re-checksummed table that breaks a rule is still refused
    doc = json.loads(table.to_json())
    doc["classes"][2]["traction"] = doc["classes"][2]["steady"]
    doc["checksum_sha256"] = _checksum(doc)
    with pytest.raises(LookupTableError, match="rules"):
        DesiredSlipTable.from_json(json.dumps(doc))
    with pytest.raises(LookupTableError, match="not valid JSON"):
        DesiredSlipTable.from_json("{nope")
    with pytest.raises(LookupTableError, match="not a terrainml desired-slip table"):
        DesiredSlipTable.from_json("{}")


FOREIGN_FILES = {
    "random.json": bytes(range(256)) * 4,  # binary: not UTF-8
    "list.json": b"[1, 2, 3]",
    "other.json": b'{"name": "agrimaro", "wheels": []}',
    "table.csv": b"id,name,traction\n0,pavement,0.16\n",
    "nan.json": b'{"schema": "terrainml.desired_slip_table", "schema_version": 1, "x": NaN}',
    "deep.json": b"[" * 100_000,
    "empty.json": b"",
}


@pytest.mark.parametrize("name", sorted(FOREIGN_FILES))
def test_foreign_file_in_place_of_the_table_is_refused_naming_it(tmp_path, name):
    path = tmp_path / name
    path.write_bytes(FOREIGN_FILES[name])
    with pytest.raises(LookupTableError) as exc:
        DesiredSlipTable.load(path)
    assert str(exc.value).startswith(f"{path}: ")


def test_rechecksummed_table_of_another_shape_is_refused(table):
    from terrainml.lookup.table import _checksum

    doc = json.loads(table.to_json())
    doc["classes"] = [1, 2, 3]  # rows that are not objects
    doc["checksum_sha256"] = _checksum(doc)
    with pytest.raises(LookupTableError, match="t.json: malformed desired-slip table"):
        DesiredSlipTable.from_json(json.dumps(doc), source="t.json")
