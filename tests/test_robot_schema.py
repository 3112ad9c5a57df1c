"""RobotSpec validation and the canonical run-table schema."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from terrainml.robot import RobotSpecError, check_wheel_count, load_robot
from terrainml.schema import SchemaError, read_run_parquet, validate_run_table, write_run_parquet


def test_builtin_specs_load():
    ag = load_robot("agrimaro")
    assert ag.n_wheels == 3 and ag.has_camera and ag.has_steering
    assert ag.wheel_xy_m[2] == (0.0, -0.756)
    hu = load_robot("husky")
    assert hu.n_wheels == 4 and not hu.has_camera and not hu.has_steering


def test_agrimaro_static_loads_equal_at_centroid():
    ag = load_robot()
    loads = ag.static_wheel_loads_n()
    assert sum(loads) == pytest.approx(80 * 9.81)
    # CoM at the triangle centroid: equal loads (design §3)
    assert np.allclose(loads, loads[0], rtol=1e-6)


@pytest.mark.parametrize("field,value,needle", [
    ("mass_kg", -3, "mass_kg"),
    ("wheel_radius_m", "big", "wheel_radius_m"),
    ("wheels", [], "wheels"),
    ("drive", "hover", "drive"),
    ("bogus_field", 1, "bogus_field"),
])
def test_invalid_spec_names_field(tmp_path: Path, field, value, needle):
    data = yaml.safe_load(load_robot().to_yaml())
    data[field] = value
    p = tmp_path / "bad.yaml"
    p.write_text(yaml.safe_dump(data))
    with pytest.raises(RobotSpecError, match=needle) as exc:
        load_robot(p)
    assert "bad.yaml" in str(exc.value)


def test_missing_field_named(tmp_path: Path):
    data = yaml.safe_load(load_robot().to_yaml())
    del data["wheel_width_m"]
    p = tmp_path / "x.yaml"
    p.write_text(yaml.safe_dump(data))
    with pytest.raises(RobotSpecError, match="missing field 'wheel_width_m'"):
        load_robot(p)


def test_duplicate_wheel_names_refused_naming_file_and_name(tmp_path: Path):
    data = yaml.safe_load(load_robot().to_yaml())
    data["wheels"][2]["name"] = data["wheels"][0]["name"]
    p = tmp_path / "twins.yaml"
    p.write_text(yaml.safe_dump(data))
    with pytest.raises(RobotSpecError) as exc:
        load_robot(p)
    msg = str(exc.value)
    assert "twins.yaml" in msg and repr(data["wheels"][0]["name"]) in msg
    assert "wheels[0]" in msg and "wheels[2]" in msg


def test_unnamed_wheel_colliding_with_a_default_name_refused(tmp_path: Path):
    # wheels[1] has no name, so it defaults to "wheel2", which wheels[0] already uses
    data = yaml.safe_load(load_robot().to_yaml())
    data["wheels"][0]["name"] = "wheel2"
    del data["wheels"][1]["name"]
    p = tmp_path / "defaults.yaml"
    p.write_text(yaml.safe_dump(data))
    with pytest.raises(RobotSpecError, match="'wheel2'") as exc:
        load_robot(p)
    assert "defaults.yaml" in str(exc.value)


def test_builtin_specs_have_unique_wheel_names():
    for name in ("agrimaro", "husky", "skidsteer_tracked"):
        wheels = [w.name for w in load_robot(name).wheels]
        assert len(set(wheels)) == len(wheels)


def test_check_wheel_count_names_source_and_both_counts():
    ag = load_robot("agrimaro")  # 3 wheels
    check_wheel_count(ag, 3, "run.mcap")  # equal: no error
    with pytest.raises(RobotSpecError) as exc:
        check_wheel_count(ag, 4, Path("logs/run.mcap"))
    msg = str(exc.value)
    assert msg.startswith(str(Path("logs/run.mcap"))) and "4 wheel" in msg and "has 3" in msg
    assert "'agrimaro'" in msg


def test_spec_roundtrip_hash_stable(tmp_path: Path):
    ag = load_robot()
    p = tmp_path / "a.yaml"
    p.write_text(ag.to_yaml())
    assert load_robot(p).sha256() == ag.sha256()


def _table(n=50):
    t = np.arange(n) * 0.01
    d = {"t_s": t, "imu_ax_mps2": 0.0, "imu_ay_mps2": 0.0, "imu_az_mps2": 9.81, "imu_yaw_rate_radps": 0.0}
    for i in (1, 2, 3):
        d[f"wheel{i}_omega_radps"] = 6.0
        d[f"wheel{i}_steer_rad"] = 0.0
        d[f"wheel{i}_current_a"] = 1.0
    return pd.DataFrame(d)


def test_validate_names_missing_column():
    df = _table().drop(columns=["imu_az_mps2"])
    with pytest.raises(SchemaError, match="imu_az_mps2"):
        validate_run_table(df, 3)


def test_validate_rejects_nonmonotonic_time():
    df = _table()
    df.loc[10, "t_s"] = 0.0
    with pytest.raises(SchemaError, match="t_s"):
        validate_run_table(df, 3)


def test_parquet_roundtrip_keeps_metadata(tmp_path: Path):
    df = validate_run_table(_table(), 3)
    p = write_run_parquet(df, tmp_path / "r.parquet", {"rate_hz": 100.0, "corrupt_per_topic": {"/imu": 2}})
    back = read_run_parquet(p)
    assert back.attrs["terrainml"]["corrupt_per_topic"] == {"/imu": 2}
    assert back.attrs["terrainml"]["schema_version"] == "1.0"
    assert back["wheels_valid"].all()
    pd.testing.assert_frame_equal(back, df)
