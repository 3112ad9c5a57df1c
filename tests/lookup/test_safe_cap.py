"""Class-free safe cap: the fallback target of design §10, hand-worked.

A 3-class catalogue of direct targets (SAE slip):

    class  traction  braking  steady
    A        0.12    -0.10    0.02
    B        0.30    -0.45    0.15
    C        0.45    -0.25    0.40

By hand: the cap in traction and steady is the largest traction target, 0.45 (C); in braking the
most negative braking target, -0.45 (B); 0 when idle. Over {A, B} only: 0.30 (B) and -0.45 (B).
Per wheel the sign follows v_long (thesis eq. 8.7-8.9).
"""

from __future__ import annotations

import pytest
import yaml

from terrainml.lookup.wheel_targets import safe_cap_per_wheel
from terrainml.lookup.table import DesiredSlipTable, LookupTableError, SafeCap
from terrainml.robot import load_robot

ROWS = {"A": (0.12, -0.10, 0.02), "B": (0.30, -0.45, 0.15), "C": (0.45, -0.25, 0.40)}


@pytest.fixture()
def three(tmp_path):
    doc = {"schema": "terrainml.terrain_catalogue", "schema_version": 1, "name": "three",
           "classes": {name: {"targets": {"traction": t, "braking": b, "steady": s},
                              "sources": {k: "assumption: hand-worked case"
                                          for k in ("traction", "braking", "steady")}}
                       for name, (t, b, s) in ROWS.items()}}
    path = tmp_path / "three.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return DesiredSlipTable.from_catalogue(path, load_robot("agrimaro"))


def test_safe_cap_hand_worked(three):
    cap = three.safe_cap()
    assert cap == SafeCap(traction=0.45, braking=-0.45, traction_class="C", braking_class="B")
    assert [cap.target(s) for s in ("idle", "steady", "traction", "braking")] == \
        [0.0, 0.45, 0.45, -0.45]
    sub = three.safe_cap(["A", "B"])
    assert (sub.traction, sub.braking, sub.traction_class) == (0.30, -0.45, "B")
    with pytest.raises(ValueError, match="unknown wheel state"):
        cap.target("cruise")
    with pytest.raises(LookupTableError, match="'Z' is not in"):
        three.safe_cap(["A", "Z"])


def test_safe_cap_stalls_no_class_and_bounds_the_slip(three):
    cap = three.safe_cap()
    for name, (t, b, s) in ROWS.items():
        assert cap.traction >= t and cap.traction >= s + 0.03, name  # no class is held below
        assert cap.braking <= b, name                                # its own target
    assert cap.traction <= 0.6 and cap.braking >= -0.6  # a cap, not a release: slip bounded


def test_safe_cap_per_wheel_signs(three):
    states = ["traction", "braking", "steady", "idle", "traction", "braking", "steady"]
    v_long = [1.0, 1.0, 0.5, 1.0, -1.0, -1.0, 0.0]
    assert safe_cap_per_wheel(states, v_long, three) == \
        [0.45, -0.45, 0.45, 0.0, -0.45, 0.45, 0.0]
    assert safe_cap_per_wheel(["traction"], [2.0], three, classes=["A"]) == [0.12]


def test_safe_cap_of_the_reference_table_is_wet_mud():
    # design §10 table: largest traction 0.524 and most negative braking -0.540, both wet mud
    cap = DesiredSlipTable.build(load_robot("agrimaro")).safe_cap()
    assert (cap.traction_class, cap.braking_class) == ("wet_mud", "wet_mud")
    assert cap.traction == pytest.approx(0.524, abs=5e-4)
    assert cap.braking == pytest.approx(-0.540, abs=5e-4)


def test_the_served_fallback_is_the_safe_cap_not_a_class():
    """Serving (stream/tick/policy.py) serves the cap on fallback, naming no class."""
    from terrainml.stream.tick.policy import ServingPolicy

    table = DesiredSlipTable.build(load_robot("agrimaro"))
    policy = ServingPolicy(table, table.class_ids, table.class_names)

    class NoClass:
        posterior, stale = None, False

        def best(self):
            return -1, 0.0

    d = policy.decide(NoClass(), estimator_ok=True, classifier_error=False, age_s=None,
                      states=["traction", "braking"], v_long=[1.0, 1.0])
    assert d.fallback and d.class_name == "none" and d.reason == "no_classification"
    assert d.slip_desired == pytest.approx((0.524, -0.540), abs=5e-4)  # wet mud's, as above
