"""``terrainml lookup build|show|plot`` (CLI contract of the lookup issue)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml
from typer.testing import CliRunner

from terrainml.cli import app
from terrainml.lookup.table import DesiredSlipTable
from terrainml.robot import load_robot

from cli_refusal import assert_refused

runner = CliRunner()


def test_show_json_has_the_contract_shape():
    res = runner.invoke(app, ["lookup", "show", "--json"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.stdout)
    assert list(doc) == ["classes"]
    assert [c["id"] for c in doc["classes"]] == list(range(8))
    first = doc["classes"][0]
    assert list(first) == ["id", "name", "traction", "braking", "steady"]
    assert first["name"] == "pavement" and 0.10 <= first["traction"] <= 0.20
    assert all(c["braking"] < 0 < c["traction"] for c in doc["classes"])


def test_build_writes_a_verified_table_and_show_reads_it(tmp_path):
    out = tmp_path / "sub" / "table.json"
    res = runner.invoke(app, ["lookup", "build", "--robot", "husky", "--out", str(out)])
    assert res.exit_code == 0, res.output
    table = DesiredSlipTable.load(out, robot=load_robot("husky"))
    assert table.robot_sha256 == load_robot("husky").sha256()
    res = runner.invoke(app, ["lookup", "show", "--table", str(out), "--robot", "husky"])
    assert res.exit_code == 0 and "pavement" in res.stdout


def test_unusable_inputs_exit_2_with_a_message_and_no_traceback(tmp_path):
    res = runner.invoke(app, ["lookup", "show", "--robot", str(tmp_path / "missing.yaml")])
    assert res.exit_code == 2 and "missing.yaml" in res.output
    assert "Traceback" not in res.output
    bad = tmp_path / "table.json"
    bad.write_text("{not json")
    res = runner.invoke(app, ["lookup", "show", "--table", str(bad)])
    assert res.exit_code == 2 and "table.json" in res.output and "Traceback" not in res.output
    out = tmp_path / "t.json"
    runner.invoke(app, ["lookup", "build", "--out", str(out)])
    res = runner.invoke(app, ["lookup", "show", "--table", str(out), "--robot", "husky"])
    assert res.exit_code == 2 and "rebuild" in res.output


def test_plot_writes_a_png(tmp_path):
    out = tmp_path / "fig.png"
    res = runner.invoke(app, ["lookup", "plot", "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 20_000


@pytest.mark.parametrize("name,content", [
    ("random.json", bytes(range(256))),
    ("shape.json", b'{"classes": {"pavement": 0.16}}'),
    ("table.csv", b"id,name,traction\n0,pavement,0.16\n"),
])
def test_foreign_table_file_is_refused_naming_it(tmp_path, name, content):
    path = tmp_path / name
    path.write_bytes(content)
    for cmd in (["lookup", "show", "--table", str(path)],
                ["lookup", "plot", "--table", str(path), "--out", str(tmp_path / "fig.png")]):
        assert_refused(runner.invoke(app, cmd), path)
    assert not (tmp_path / "fig.png").exists()


def test_unwritable_output_is_refused_before_building(tmp_path):
    blocker = tmp_path / "blocker"
    blocker.write_text("a file, not a folder")
    assert_refused(runner.invoke(app, ["lookup", "build", "--out", str(blocker / "t.json")]), blocker / "t.json")
    assert_refused(runner.invoke(app, ["lookup", "plot", "--out", str(blocker / "f.png")]), blocker / "f.png")
    if Path("/proc/self").is_dir():  # fails for root too
        assert_refused(runner.invoke(app, ["lookup", "build", "--out", "/proc/t.json"]), "/proc/t.json")


def test_build_from_a_catalogue_for_a_robot_spec_file(tmp_path):
    robot_yaml = tmp_path / "heavy_husky.yaml"
    spec = load_robot("husky").to_dict()
    spec.update(name="heavy_husky", mass_kg=100.0)
    robot_yaml.write_text(yaml.safe_dump(spec))
    out = tmp_path / "t.json"
    res = runner.invoke(app, ["lookup", "build", "--catalogue", "borealtc", "--robot",
                              str(robot_yaml), "--out", str(out)])
    assert res.exit_code == 0, res.output
    table = DesiredSlipTable.load(out, robot=load_robot(robot_yaml))
    assert table.class_names == ("ASPHALT", "FLOORING", "ICE", "SANDY_LOAM", "SNOW")
    assert table.wheel_loads_n == pytest.approx([100.0 * 9.81 / 4] * 4, rel=1e-3)
    res = runner.invoke(app, ["lookup", "show", "--catalogue", "borealtc", "--classes",
                              "SNOW,ICE", "--json"])
    assert res.exit_code == 0, res.output
    assert [c["name"] for c in json.loads(res.stdout)["classes"]] == ["SNOW", "ICE"]


def test_bad_catalogue_is_refused_naming_file_class_and_field(tmp_path):
    cat = tmp_path / "cat.yaml"
    cat.write_text("schema: terrainml.terrain_catalogue\nschema_version: 1\nclasses:\n"
                   "  GRAVEL:\n    targets: {traction: 0.9, braking: -0.2, steady: 0.1}\n"
                   "    sources: {traction: a, braking: b, steady: c}\n")
    assert_refused(runner.invoke(app, ["lookup", "build", "--catalogue", str(cat), "--out",
                                 str(tmp_path / "t.json")]), cat, "class GRAVEL", "traction")
    assert not (tmp_path / "t.json").exists()
    assert_refused(runner.invoke(app, ["lookup", "show", "--catalogue", "borealtc", "--classes",
                                 "ASPHALT,GRASS"]), "borealtc", "GRASS")
    assert_refused(runner.invoke(app, ["lookup", "show", "--catalogue", str(tmp_path / "no.yaml")]),
             "no.yaml")
