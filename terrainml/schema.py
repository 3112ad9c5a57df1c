"""Canonical run table (design §5): one row per base-rate tick, SI units, body frame.

This module is the single place that names every column, its unit and dtype. Readers produce
tables that pass :func:`validate_run_table`; every later stage consumes them.

Column groups
-------------
time      ``t_s`` (s, monotonic, from the log's first message)
wheels    ``wheel{i}_omega_radps``, ``wheel{i}_steer_rad``, ``wheel{i}_current_a``, optional
          ``wheel{i}_cmd_omega_radps`` (i = 1..N)
imu       ``imu_ax_mps2``, ``imu_ay_mps2``, ``imu_az_mps2``, ``imu_yaw_rate_radps``, optional ``imu_yaw_rad``
cam       ``cam_vx_mps``, ``cam_vy_mps``, ``cam_yaw_rate_radps``, ``cam_yaw_rad``, optional ``cam_confidence``
          (velocities of the camera mount point, expressed in body axes)
cmd       optional ``cmd_vx_mps``, ``cmd_vy_mps``, ``cmd_yaw_rate_radps``
validity  ``{group}_valid`` (bool) for groups wheels, steer, current, imu, cam, cmd
labels    optional ``terrain`` (class id), ``run_id``
truth     (simulator only) ``gt_vx_mps``, ``gt_vy_mps``, ``gt_yaw_rate_radps``, ``gt_x_m``, ``gt_y_m``,
          ``gt_yaw_rad``, ``gt_slip{i}``, ``gt_state{i}``
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from terrainml.atomic import atomic_output

SCHEMA_VERSION = "1.0"
DEFAULT_RATE_HZ = 100.0
METADATA_KEY = b"terrainml"


class SchemaError(ValueError):
    """A run table does not satisfy the canonical schema (the message names the column)."""


@dataclass(frozen=True)
class Column:
    name: str
    unit: str
    dtype: str  # "float64" | "bool" | "int64" | "string"
    group: str
    required: bool
    description: str


# sensor groups that carry a {group}_valid column
VALID_GROUPS = ("wheels", "steer", "current", "imu", "cam", "cmd")
# wheel dynamic states (design §7.2), in code order
WHEEL_STATES = ("idle", "steady", "traction", "braking")
#: the wheel states of a moving wheel (every state but idle)
MOVING_WHEEL_STATES = WHEEL_STATES[1:]


#: suffix of each per-wheel column kind (:func:`wheel_col`)
WHEEL_COLUMN_SUFFIX = {"omega": "omega_radps", "steer": "steer_rad", "current": "current_a",
                       "cmd_omega": "cmd_omega_radps"}


def wheel_columns(i: int) -> list[Column]:
    return [
        Column(wheel_col("omega", i), "rad/s", "float64", "wheels", True,
               f"wheel {i} angular speed from the encoder, after the gear ratio"),
        Column(wheel_col("steer", i), "rad", "float64", "steer", True,
               f"wheel {i} steering angle (0 for fixed wheels)"),
        Column(wheel_col("current", i), "A", "float64", "current", True,
               f"wheel {i} motor current, positive when driving forward"),
        Column(wheel_col("cmd_omega", i), "rad/s", "float64", "wheels", False,
               f"wheel {i} commanded angular speed"),
    ]


BASE_COLUMNS: list[Column] = [
    Column("t_s", "s", "float64", "time", True, "time since the log's first message"),
    Column("imu_ax_mps2", "m/s^2", "float64", "imu", True, "specific force along body x"),
    Column("imu_ay_mps2", "m/s^2", "float64", "imu", True, "specific force along body y"),
    Column("imu_az_mps2", "m/s^2", "float64", "imu", True, "specific force along body z (+9.81 at rest)"),
    Column("imu_yaw_rate_radps", "rad/s", "float64", "imu", True, "gyro rate about body z"),
    Column("imu_yaw_rad", "rad", "float64", "imu", False, "IMU fused yaw"),
    Column("imu_roll_rate_radps", "rad/s", "float64", "imu", False, "gyro rate about body x"),
    Column("imu_pitch_rate_radps", "rad/s", "float64", "imu", False, "gyro rate about body y"),
    Column("cam_vx_mps", "m/s", "float64", "cam", False, "camera-mount velocity along body x"),
    Column("cam_vy_mps", "m/s", "float64", "cam", False, "camera-mount velocity along body y"),
    Column("cam_yaw_rate_radps", "rad/s", "float64", "cam", False, "camera yaw rate about body z"),
    Column("cam_yaw_rad", "rad", "float64", "cam", False, "camera yaw, zeroed at the first valid pose"),
    Column("cam_confidence", "-", "float64", "cam", False, "tracking confidence 0..3"),
    Column("cmd_vx_mps", "m/s", "float64", "cmd", False, "commanded body velocity x"),
    Column("cmd_vy_mps", "m/s", "float64", "cmd", False, "commanded body velocity y"),
    Column("cmd_yaw_rate_radps", "rad/s", "float64", "cmd", False, "commanded yaw rate"),
    Column("terrain", "-", "int64", "labels", False, "terrain class id (-1 unknown)"),
    Column("run_id", "-", "string", "labels", False, "run identifier (groups for CV)"),
    Column("gt_vx_mps", "m/s", "float64", "truth", False, "true body velocity x"),
    Column("gt_vy_mps", "m/s", "float64", "truth", False, "true body velocity y"),
    Column("gt_yaw_rate_radps", "rad/s", "float64", "truth", False, "true yaw rate"),
    Column("gt_x_m", "m", "float64", "truth", False, "true world x"),
    Column("gt_y_m", "m", "float64", "truth", False, "true world y"),
    Column("gt_yaw_rad", "rad", "float64", "truth", False, "true world yaw"),
]


def truth_wheel_columns(i: int) -> list[Column]:
    return [
        Column(f"gt_slip{i}", "-", "float64", "truth", False, f"true slip of wheel {i} (design §7.1)"),
        Column(f"gt_state{i}", "-", "string", "truth", False, f"true dynamic state of wheel {i}"),
    ]


#: largest magnitude a sensor reading can have, by unit: 1000 rad/s (~9,500 rpm), 1000 A, 1000 m/s^2
#: (~100 g), 100 m/s, 1e4 rad (an unwrapped yaw of 1,600 turns). A finite value beyond is a broken
#: sample, never a reading: it invalidates its sensor group like a NaN (the stream's health rule)
PHYSICAL_LIMITS = {"rad/s": 1e3, "A": 1e3, "m/s^2": 1e3, "m/s": 1e2, "rad": 1e4}


def physical_limit(name: str, n_wheels: int) -> float:
    """Largest |value| of canonical column ``name`` (:data:`PHYSICAL_LIMITS` by its unit; inf for
    columns without one, labels, truth and unknown names)."""
    col = column_map(n_wheels).get(name)
    if col is None or col.group in ("labels", "truth", "validity", "time"):
        return float("inf")
    return PHYSICAL_LIMITS.get(col.unit, float("inf"))


def valid_column(group: str) -> Column:
    # not required on input: derived from finiteness when a producer does not supply it
    return Column(f"{group}_valid", "-", "bool", "validity", False,
                  f"True where the {group} group has a fresh, finite sample")


def columns(n_wheels: int) -> list[Column]:
    """All canonical columns for a robot with ``n_wheels`` wheels."""
    cols = list(BASE_COLUMNS)
    for i in range(1, n_wheels + 1):
        cols += wheel_columns(i)
    for i in range(1, n_wheels + 1):
        cols += truth_wheel_columns(i)
    cols += [valid_column(g) for g in VALID_GROUPS]
    return cols


def column_map(n_wheels: int) -> dict[str, Column]:
    return {c.name: c for c in columns(n_wheels)}


def group_columns(group: str, n_wheels: int) -> list[str]:
    """Names of the data columns of one validity group (e.g. ``"cam"``)."""
    return [c.name for c in columns(n_wheels) if c.group == group]


def wheel_col(kind: str, i: int) -> str:
    """``wheel_col("omega", 2) -> "wheel2_omega_radps"`` (kind: a key of :data:`WHEEL_COLUMN_SUFFIX`)."""
    return f"wheel{i}_{WHEEL_COLUMN_SUFFIX[kind]}"


def infer_n_wheels(df: pd.DataFrame) -> int:
    n = 0
    while wheel_col("omega", n + 1) in df.columns:
        n += 1
    return n


# --------------------------------------------------------------------- validation
def validate_run_table(df: pd.DataFrame, n_wheels: int | None = None, *, source: str = "run table",
                       strict: bool = False) -> pd.DataFrame:
    """Check a run table against the schema and return it with canonical dtypes.

    Parameters
    ----------
    df : DataFrame, shape (n_ticks, n_columns)
    n_wheels : expected number of wheels; inferred from ``wheel{i}_omega_radps`` if None.
    source : name used in error messages (file path).
    strict : if True, unknown columns are an error; otherwise they are kept.

    Raises
    ------
    SchemaError naming the missing/invalid column.
    """
    if n_wheels is None:
        n_wheels = infer_n_wheels(df)
    if n_wheels < 1:
        raise SchemaError(f"{source}: missing column 'wheel1_omega_radps' (no wheel columns found)")
    spec = column_map(n_wheels)
    for col in spec.values():
        if col.required and col.name not in df.columns:
            raise SchemaError(f"{source}: missing required column '{col.name}' ({col.description}, {col.unit})")
    if strict:
        unknown = [c for c in df.columns if c not in spec]
        if unknown:
            raise SchemaError(f"{source}: unknown column(s) {', '.join(map(repr, unknown))}")
    out = df.copy()
    for name in out.columns:
        col = spec.get(name)
        if col is None:
            continue
        try:
            if col.dtype == "float64":
                out[name] = pd.to_numeric(out[name], errors="raise").astype("float64")
            elif col.dtype == "bool":
                if out[name].isna().any():
                    raise SchemaError(f"{source}: column '{name}' (bool) has missing values")
                out[name] = out[name].astype(bool)
            elif col.dtype == "int64":
                out[name] = pd.to_numeric(out[name], errors="raise").fillna(-1).astype("int64")
            elif col.dtype == "string":
                out[name] = out[name].astype(str)
        except (ValueError, TypeError) as exc:
            raise SchemaError(f"{source}: column '{name}' cannot be read as {col.dtype} ({col.unit}): {exc}") from None
    t = out["t_s"].to_numpy()
    if len(t) and not np.all(np.isfinite(t)):
        raise SchemaError(f"{source}: column 't_s' has non-finite values")
    if len(t) > 1 and np.any(np.diff(t) <= 0):
        bad = int(np.argmax(np.diff(t) <= 0)) + 1
        raise SchemaError(f"{source}: column 't_s' is not strictly increasing (row {bad})")
    for g in VALID_GROUPS:
        vname = f"{g}_valid"
        present = [c for c in group_columns(g, n_wheels)
                   if c in out.columns and (spec[c].required or g in ("cam", "cmd"))
                   and c != "cam_confidence"]
        if vname not in out.columns and present:
            # derive validity from finiteness when a producer did not supply it
            out[vname] = np.isfinite(out[present].to_numpy(dtype=float)).all(axis=1)
    return out


# --------------------------------------------------------------------- parquet
def table_metadata(df: pd.DataFrame) -> dict[str, Any]:
    """The terrainml metadata attached to a table (``df.attrs['terrainml']``), or {}."""
    return dict(df.attrs.get("terrainml", {}))


def make_metadata(*, robot_json: str | None = None, source_file: str | None = None,
                  source_sha256: str | None = None, topic_map: dict | None = None,
                  rate_hz: float = DEFAULT_RATE_HZ, skipped: dict[str, int] | None = None,
                  corrupt: dict[str, int] | None = None, **extra: Any) -> dict[str, Any]:
    """Build the design §5 table metadata."""
    meta = {
        "schema_version": SCHEMA_VERSION,
        "robot_spec": robot_json,
        "source_file": source_file,
        "source_sha256": source_sha256,
        "topic_map": topic_map,
        "rate_hz": float(rate_hz),
        "skipped_per_topic": dict(skipped or {}),
        "corrupt_per_topic": dict(corrupt or {}),
    }
    meta.update(extra)
    return meta


def write_run_parquet(df: pd.DataFrame, path: str | Path, metadata: dict[str, Any] | None = None) -> Path:
    """Write a validated run table to Parquet with the terrainml key-value metadata.

    Written whole or not at all (:func:`terrainml.atomic.atomic_output`); a failure raises
    :class:`terrainml.atomic.OutputWriteError` naming ``path``."""
    path = Path(path)
    meta = dict(table_metadata(df))
    meta.update(metadata or {})
    meta.setdefault("schema_version", SCHEMA_VERSION)
    clean = df.copy()
    clean.attrs = {}
    table = pa.Table.from_pandas(clean, preserve_index=False)
    kv = dict(table.schema.metadata or {})
    kv[METADATA_KEY] = json.dumps(meta, default=str).encode()
    with atomic_output(path) as tmp:
        pq.write_table(table.replace_schema_metadata(kv), tmp)
    return path


def read_run_parquet(path: str | Path, *, validate: bool = True) -> pd.DataFrame:
    """Read a run table written by :func:`write_run_parquet` (metadata in ``df.attrs['terrainml']``)."""
    path = Path(path)
    if not path.is_file():
        raise SchemaError(f"{path}: file not found")
    try:
        table = pq.read_table(path)
    except Exception as exc:  # pyarrow raises several types for non-parquet input
        raise SchemaError(f"{path}: not a readable Parquet file ({exc})") from None
    kv = table.schema.metadata or {}
    meta = json.loads(kv[METADATA_KEY]) if METADATA_KEY in kv else {}
    df = table.to_pandas()
    if validate:
        df = validate_run_table(df, source=str(path))
    df.attrs["terrainml"] = meta
    return df


# --------------------------------------------------------------------- estimator (EST) rows
#: the EKF's body states in an estimator (EST) row, in order: pose (m, m, rad), body velocity
#: (m/s, m/s), yaw rate (rad/s), body acceleration (m/s^2, m/s^2)
EST_BODY_COLUMNS = ("ekf_x_m", "ekf_y_m", "ekf_yaw_rad", "ekf_vx_mps", "ekf_vy_mps",
                    "ekf_yaw_rate_radps", "ekf_ax_mps2", "ekf_ay_mps2")
#: the body speeds and yaw rate (m/s, m/s, rad/s): a tick is healthy only where they are finite
EST_VX, EST_VY, EST_YAW_RATE = EST_BODY_COLUMNS[3:6]
#: the EKF's gyro bias (rad/s)
EST_GYRO_BIAS = "ekf_gyro_bias_radps"
#: the estimator's health flag (bool): EKF fresh and sane (contract 2)
EST_OK = "estimator_ok"
#: the EKF's consistency and slip availability: NIS (-), its degrees of freedom (int), camera
#: healthy so measured slip is available (bool)
EST_HEALTH_COLUMNS = ("nis", "nis_dof", EST_OK, "slip_available")
#: suffix of each per-wheel EST column kind (:func:`est_wheel_col`), in the row's order
EST_WHEEL_KINDS = ("steer", "slip", "state", "v_long")


def est_wheel_col(kind: str, i: int) -> str:
    """An estimator (EST) row's per-wheel column: ``est_wheel_col("v_long", 2) -> "v_long2_mps"``
    (kind: one of :data:`EST_WHEEL_KINDS`; steer in rad, slip -, state a :data:`WHEEL_STATES`
    name, v_long in m/s)."""
    return {"steer": f"ekf_steer{i}_rad", "slip": f"slip{i}", "state": f"state{i}",
            "v_long": f"v_long{i}_mps"}[kind]


def est_columns(n_wheels: int) -> list[str]:
    """The estimated columns of an EST row (without pass-through columns), in order."""
    wheels = range(1, n_wheels + 1)
    return ["t_s", *EST_BODY_COLUMNS, *(est_wheel_col("steer", i) for i in wheels), EST_GYRO_BIAS,
            *(est_wheel_col(kind, i) for kind in EST_WHEEL_KINDS[1:] for i in wheels),
            *EST_HEALTH_COLUMNS]
