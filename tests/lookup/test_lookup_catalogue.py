"""Terrain catalogues and the table built from them (design §10).

Independent truth: the targets design §10 / docs/lookup.md publish for the reference robot (3 dp),
the nominal class parameters of ``terramechanics`` (the simulator's), the analytic Burckhardt
peak s* = ln(c1 c2 / c3) / c2, the BorealTC folder names, and for the robot dependence the
closed forms of Bekker sinkage and the contact-patch average of Wong's hump-type shear curve,
written out here and integrated with scipy (not the code's closed form).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import pytest
import yaml
from scipy.integrate import quad
from scipy.optimize import minimize_scalar

from terrainml.classes import TERRAIN_CLASSES
from terrainml.lookup import terramechanics as tm
from terrainml.lookup.catalogue import CatalogueError, load_catalogue
from terrainml.lookup.table import DesiredSlipTable, LookupTableError
from terrainml.robot import load_robot

# design §10 table (reference robot), as `terrainml lookup show` printed it
PUBLISHED = {  # name: (traction, braking, steady)
    "pavement": (0.160, -0.160, 0.000), "compacted_dirt": (0.142, -0.145, 0.035),
    "short_grass": (0.230, -0.174, 0.125), "gravel_on_firm_soil": (0.259, -0.192, 0.134),
    "tall_damp_grass": (0.299, -0.247, 0.190), "tilled_loam": (0.330, -0.425, 0.200),
    "dry_sand": (0.421, -0.453, 0.300), "wet_mud": (0.524, -0.540, 0.420),
}
BOREALTC = ["ASPHALT", "FLOORING", "ICE", "SANDY_LOAM", "SNOW"]
BOREALTC_DIR = Path(__file__).resolve().parents[2] / ".." / "shared" / "datasets" / "borealtc"


@pytest.fixture(scope="module")
def reference_table():
    return DesiredSlipTable.from_catalogue("reference", load_robot("agrimaro"))


@pytest.fixture(scope="module")
def borealtc_table():
    return DesiredSlipTable.from_catalogue("borealtc", load_robot("husky"))


# ---------------------------------------------------------------- the reference catalogue
def test_reference_catalogue_holds_the_simulated_classes_parameters():
    cat = load_catalogue("reference")
    assert cat.class_names == TERRAIN_CLASSES
    for cid, c in enumerate(cat.classes):
        assert dataclasses.replace(c.params, class_id=cid) == tm.nominal_params(cid), c.name
    assert [c.name for c in cat.classes if c.rigid_surface] == ["pavement", "compacted_dirt"]


def test_reference_catalogue_reproduces_the_published_table(reference_table):
    assert reference_table.class_names == TERRAIN_CLASSES
    for name, (s_t, s_b, s_s) in PUBLISHED.items():
        assert reference_table.target(name, "traction") == pytest.approx(s_t, abs=5e-4), name
        assert reference_table.target(name, "braking") == pytest.approx(s_b, abs=5e-4), name
        assert reference_table.target(name, "steady") == pytest.approx(s_s, abs=5e-4), name


def test_reference_catalogue_table_equals_the_default_table(reference_table):
    default = DesiredSlipTable.build(load_robot("agrimaro"))
    for a, b in zip(default.rows, reference_table.rows):
        da, db = a.to_dict(), b.to_dict()
        assert db.pop("sources") and not da.pop("sources")  # provenance only in the catalogue
        assert da == db, a.name
    assert default.robot_sha256 == reference_table.robot_sha256
    assert reference_table.meta["rules"] == default.meta["rules"]
    assert reference_table.meta["catalogue"]["name"] == "reference"


# ---------------------------------------------------------------- BorealTC
def test_borealtc_catalogue_names_the_dataset_classes_exactly():
    assert list(load_catalogue("borealtc").class_names) == BOREALTC
    if BOREALTC_DIR.is_dir():  # the shipped dataset's folders (the borealtc dataset spec)
        folders = sorted(d.name for d in BOREALTC_DIR.iterdir()
                         if d.is_dir() and any(d.glob("pro_*.csv")))
        assert folders == BOREALTC


def test_borealtc_table_builds_with_positive_traction_peaks(borealtc_table):
    assert borealtc_table.class_names == tuple(BOREALTC)
    assert borealtc_table.check_rules() == []
    for row in borealtc_table.rows:
        assert 0.0 < row.traction < 1.0, row.name
        assert row.braking < 0.0 <= row.steady, row.name
        assert row.sources, row.name  # provenance travels with the table
    # asphalt: Burckhardt dry-asphalt peak, analytic (rigid surface: rule satisfied, no clamp)
    s_star = math.log(1.2801 * 23.99 / 0.52) / 23.99
    assert borealtc_table.target("ASPHALT", "traction") == pytest.approx(s_star, abs=0.0015)
    assert borealtc_table.row("ASPHALT").notes == ()


def test_every_borealtc_value_has_a_source_or_a_reasoned_assumption():
    for c in load_catalogue("borealtc").classes:
        given = {k for k, v in dataclasses.asdict(c.params).items()
                 if k not in ("class_id", "name", "model", "sources")
                 and v != getattr(tm.TerrainParams, k, None)}
        # every parameter that differs from the defaults has a source (deg given as deg)
        assert given <= set(c.sources) | {"friction_angle_rad"}, c.name
        for field_name, src in c.sources.items():
            if src.lower().startswith("assumption"):
                assert len(src.split(":", 1)[1].strip()) > 10, (c.name, field_name)


def test_table_round_trips_through_json_with_names_and_sources(borealtc_table):
    back = DesiredSlipTable.from_json(borealtc_table.to_json(), robot=load_robot("husky"))
    assert back.class_names == borealtc_table.class_names
    assert back.row("SNOW").sources == borealtc_table.row("SNOW").sources
    assert [r.rigid_surface for r in back.rows] == [True, True, False, False, False]


# ---------------------------------------------------------------- robot dependence, by hand
HUMP_SOIL = {"schema": "terrainml.terrain_catalogue", "schema_version": 1, "name": "hand",
             "classes": {"soil": {"model": "soil", "params": {
                 "cohesion_pa": 2000.0, "friction_angle_deg": 30.0, "n_exp": 1.0, "k_c": 20000.0,
                 "k_phi": 1.0e6, "shear_modulus_m": 0.01, "residual_ratio": 0.8,
                 "slip_sinkage": 0.0, "free_slip": 0.0},
                 "sources": {}}}}
for _k in HUMP_SOIL["classes"]["soil"]["params"]:
    HUMP_SOIL["classes"]["soil"]["sources"][_k] = "assumption: a hand-checkable soil"


def _hump_patch_average(u: float, kr: float) -> float:
    """Wong's hump-type tau/tau_max averaged over the patch: (1/u) int_0^u f(v) dv."""
    c = 1.0 / (kr * (1.0 - math.exp(-1.0))) - 1.0
    f = lambda v: kr * (1.0 + c * math.exp(1.0 - v)) * (1.0 - math.exp(-v))  # noqa: E731
    return quad(f, 0.0, u)[0] / u


def _hand_peak_slip(robot, load_n: float) -> float:
    """Traction peak of the hand soil: with no slip-sinkage the sinkage, the contact length and
    the resistance do not depend on slip, so mu_net peaks where the patch-average shear does,
    u* = s L / K: s* = u* K / L, L = sqrt(2 R z0) + flat, z0 = Bekker rigid-wheel sinkage."""
    n, k_c, k_phi, k_w = 1.0, 20000.0, 1.0e6, 0.01
    r_w, b, flat = robot.wheel_radius_m, robot.wheel_width_m, robot.tyre_flat_m
    z0 = (3.0 * load_n / ((3.0 - n) * (k_c + b * k_phi) * math.sqrt(2.0 * r_w))) ** (2.0 / (2.0 * n + 1.0))
    length = math.sqrt(2.0 * r_w * z0) + flat
    u_star = minimize_scalar(lambda u: -_hump_patch_average(u, 0.8), bounds=(0.1, 20.0),
                             method="bounded", options={"xatol": 1e-8}).x
    return u_star * k_w / length


def test_heavier_load_per_wheel_moves_the_bekker_peak_as_the_equations_say(tmp_path):
    path = tmp_path / "hand.yaml"
    path.write_text(yaml.safe_dump(HUMP_SOIL))
    light = load_robot("agrimaro")
    heavy = dataclasses.replace(light, mass_kg=2.0 * light.mass_kg)
    t_light = DesiredSlipTable.from_catalogue(path, light)
    t_heavy = DesiredSlipTable.from_catalogue(path, heavy)
    w_light, w_heavy = light.static_wheel_loads_n()[0], heavy.static_wheel_loads_n()[0]
    assert w_heavy == pytest.approx(2.0 * w_light)
    s_light, s_heavy = _hand_peak_slip(light, w_light), _hand_peak_slip(heavy, w_heavy)
    for table, s_hand in ((t_light, s_light), (t_heavy, s_heavy)):
        row = table.row("soil")
        assert row.traction_kind == "peak" and row.notes == ()
        assert row.traction == pytest.approx(s_hand, abs=0.0015)
    # deeper sinkage -> longer contact patch -> the shear peak is reached at smaller slip
    assert t_heavy.target("soil", "traction") < t_light.target("soil", "traction") - 0.005


def test_direct_targets_do_not_depend_on_the_robot(tmp_path):
    path = tmp_path / "given.yaml"
    path.write_text(yaml.safe_dump(THREE_CLASSES))
    a = DesiredSlipTable.from_catalogue(path, load_robot("agrimaro"))
    b = DesiredSlipTable.from_catalogue(path, load_robot("husky"))
    assert a.to_summary() == b.to_summary()
    assert a.robot_sha256 != b.robot_sha256


# ---------------------------------------------------------------- classes by name
THREE_CLASSES = {
    "schema": "terrainml.terrain_catalogue", "schema_version": 1, "name": "three",
    "classes": {
        "A": {"targets": {"traction": 0.12, "braking": -0.10, "steady": 0.02},
              "sources": {"traction": "assumption: hand-worked case", "braking": "assumption: "
                          "hand-worked case", "steady": "assumption: hand-worked case"}},
        "B": {"targets": {"traction": 0.30, "braking": -0.45, "steady": 0.15},
              "sources": {"traction": "test", "braking": "test", "steady": "test"}},
        "C": {"targets": {"traction": 0.45, "braking": -0.25, "steady": 0.40},
              "sources": {"traction": "test", "braking": "test", "steady": "test"}},
    }}


@pytest.fixture()
def three(tmp_path):
    path = tmp_path / "three.yaml"
    path.write_text(yaml.safe_dump(THREE_CLASSES, sort_keys=False))
    return DesiredSlipTable.from_catalogue(path, load_robot("agrimaro"))


def test_lookup_by_name_and_unknown_name(three, borealtc_table):
    assert three.target("B", "braking") == -0.45
    assert three.target("B", "steady") == three.target(1, "steady") == 0.15
    assert three.target("C", "idle") == 0.0
    with pytest.raises(LookupTableError, match=r"'pavement' is not in the desired-slip table.*A, B, C"):
        three.target("pavement", "traction")
    with pytest.raises(LookupTableError, match="'compacted_dirt' is not in"):
        borealtc_table.row("compacted_dirt")
    with pytest.raises(ValueError, match="unknown wheel state"):
        three.target("A", "cruise")


def test_class_set_order_gives_the_ids_not_the_targets(tmp_path):
    path = tmp_path / "three.yaml"
    path.write_text(yaml.safe_dump(THREE_CLASSES))
    t = DesiredSlipTable.from_catalogue(path, class_names=["C", "A"])
    assert t.class_names == ("C", "A") and t.class_ids == (0, 1)
    assert t.target("A", "traction") == 0.12 and t.target(0, "traction") == 0.45


def test_check_classes_refuses_a_table_without_the_model_classes_at_their_ids(three, borealtc_table):
    """What serving checks on load: the policy looks targets up by id, so the table's class cid
    must be the model's class cid; a table with more classes serves a model of some of them."""
    three.check_classes([0, 1, 2], ["A", "B", "C"], "model runs/m")
    three.check_classes([0, 2], ["A", "C"], "m")
    with pytest.raises(LookupTableError, match=r"by id: \[\(0, 'C'\), \(2, 'A'\)\] differ"):
        three.check_classes([0, 1, 2], ["C", "B", "A"], "m")  # the same set under other ids
    with pytest.raises(LookupTableError) as exc:
        borealtc_table.check_classes(range(8), list(TERRAIN_CLASSES), "model runs/m")
    msg = str(exc.value)
    assert msg.startswith("model runs/m: the desired-slip table's classes")
    assert "ASPHALT" in msg and "wet_mud" in msg
    with pytest.raises(LookupTableError, match=r"by id: \[\(3, 'D'\)\]"):
        three.check_classes([0, 3], ["A", "D"], "m")  # an id beyond the table


def test_a_class_set_the_catalogue_lacks_is_refused_naming_the_file_and_classes():
    with pytest.raises(CatalogueError, match=r"^borealtc: missing classes \['GRASS'\]"):
        DesiredSlipTable.from_catalogue("borealtc", load_robot("husky"), class_names=["ASPHALT", "GRASS"])


# ---------------------------------------------------------------- validation
def _mutated(change):
    doc = yaml.safe_load(yaml.safe_dump(THREE_CLASSES))
    doc["classes"]["D"] = {"model": "burckhardt", "params": {"c1": 1.2, "c2": 25.0, "c3": 0.5},
                           "sources": {"c1": "x", "c2": "x", "c3": "x"}}
    change(doc)
    return doc


def _set(path, value):
    def change(doc):
        d = doc
        for k in path[:-1]:
            d = d[k]
        if value is _DELETE:
            del d[path[-1]]
        else:
            d[path[-1]] = value
    return change


_DELETE = object()
BAD = [  # (id, change, needles in the message besides the file)
    ("unknown_top_field", _set(["colour"], "red"), ["unknown field(s) ['colour']"]),
    ("unknown_class_field", _set(["classes", "A", "colour"], 1), ["class A", "'colour'"]),
    ("unknown_param", _set(["classes", "D", "params", "grip"], 1.0), ["class D", "'grip'"]),
    ("param_of_another_model", _set(["classes", "D", "params", "k_phi"], 1.0e6),
     ["class D", "'k_phi'", "model burckhardt"]),
    ("missing_required", _set(["classes", "D", "params", "c2"], _DELETE),
     ["class D", "missing field c2"]),
    ("missing_source", _set(["classes", "D", "sources", "c3"], _DELETE),
     ["class D, field c3", "no source"]),
    ("bare_assumption", _set(["classes", "D", "sources", "c3"], "assumption"),
     ["class D, field c3", "needs its reason"]),
    ("source_of_nothing", _set(["classes", "D", "sources", "crr"], "x"), ["class D", "'crr'"]),
    ("negative_c1", _set(["classes", "D", "params", "c1"], -1.0),
     ["class D, field c1", "out of range"]),
    ("nan", _set(["classes", "D", "params", "c1"], float("nan")), ["class D, field c1", "finite"]),
    ("text_value", _set(["classes", "D", "params", "c2"], "fast"),
     ["class D, field c2", "expected a number"]),
    ("traction_too_large", _set(["classes", "B", "targets", "traction"], 0.7),
     ["class B, field traction", "out of range"]),
    ("braking_positive", _set(["classes", "B", "targets", "braking"], 0.1),
     ["class B, field braking", "out of range"]),
    ("margin_rule", _set(["classes", "C", "targets", "steady"], 0.43),
     ["class C, field traction", "below steady"]),
    ("rigid_rule", _set(["classes", "C", "rigid_surface"], True),
     ["class C, field traction", "rigid surface"]),
    ("missing_target", _set(["classes", "A", "targets", "steady"], _DELETE),
     ["class A", "targets lack ['steady']"]),
    ("both_kinds", _set(["classes", "A", "params"], {"c1": 1.0}),
     ["class A", "exactly one of"]),
    ("bad_model", _set(["classes", "D", "model"], "pacejka"), ["class D, field model"]),
    ("version", _set(["schema_version"], 2), ["schema_version 2"]),
    ("no_classes", _set(["classes"], {}), ["'classes'"]),
]


@pytest.mark.parametrize("change,needles", [b[1:] for b in BAD], ids=[b[0] for b in BAD])
def test_catalogue_errors_name_the_file_class_and_field(tmp_path, change, needles):
    path = tmp_path / "cat.yaml"
    path.write_text(yaml.safe_dump(_mutated(change), sort_keys=False))
    with pytest.raises(CatalogueError) as exc:
        DesiredSlipTable.from_catalogue(path)
    msg = str(exc.value)
    assert msg.startswith(f"{path}: "), msg
    for n in needles:
        assert n in msg, (n, msg)


def test_soil_ranges_are_checked(tmp_path):
    doc = yaml.safe_load(yaml.safe_dump(HUMP_SOIL))
    doc["classes"]["soil"]["params"]["friction_angle_deg"] = 75.0
    path = tmp_path / "soil.yaml"
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(CatalogueError, match=r"class soil, field friction_angle_deg: 75 out of "
                                             r"range \[0, 60\]"):
        load_catalogue(path)


@pytest.mark.parametrize("text,needle", [
    ("schema: terrainml.terrain_catalogue\nschema: x\n", "given twice"),
    ("{not: [yaml", "not valid YAML"),
    ("- 1\n- 2\n", "not a terrain catalogue"),
])
def test_unreadable_catalogue_files_are_refused_naming_them(tmp_path, text, needle):
    path = tmp_path / "c.yaml"
    path.write_text(text)
    with pytest.raises(CatalogueError, match=needle) as exc:
        load_catalogue(path)
    assert str(exc.value).startswith(f"{path}: ")
    with pytest.raises(CatalogueError, match="no such terrain catalogue file"):
        load_catalogue(tmp_path / "missing.yaml")
