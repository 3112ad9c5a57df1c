"""Reader for the BorealTC dataset layout (LaRocque et al., IROS 2024; CC0).

Layout: a folder of ``<CLASS>/imu_XX.csv`` (about 100 Hz: ``time,wx,wy,wz,ax,ay,az`` in rad/s and
m/s^2) and ``<CLASS>/pro_XX.csv`` (about 6.5 Hz: ``time,curL,curR,velL,velR`` in A and m/s);
files with the same ``XX`` are one run. Columns are found by header name (other exports of this
robot order them differently), sampling rates are taken from the data.

Mapping to the canonical run table of a skid-steer robot (Husky spec: wheel1 front-left,
wheel2 front-right, wheel3 rear-left, wheel4 rear-right). The Husky has one motor per side, so
the left motor's current and speed are given to wheels 1 and 3, the right motor's to 2 and 4
(``wheel{i}_current_a`` is the *side* motor current, documented departure from per-wheel
currents). Wheel speed is ``vel / R``; steering is 0. The IMU is taken as already in body axes
(gravity on +z in the files). Runs whose IMU file is missing are returned with wheel channels
only (``imu_valid`` False) and listed in the report.

The terrain classes are the dataset's own (folder names, sorted); ``terrain`` holds the index into
``classes`` and the class names travel in the table metadata.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from terrainml.robot import RobotSpec, load_robot
from terrainml.schema import DEFAULT_RATE_HZ, make_metadata, validate_run_table

IMU_ALIASES = {
    "time": ("time", "t", "timestamp", "stamp"),
    "wx": ("wx", "gyro_x", "angular_velocity_x"),
    "wy": ("wy", "gyro_y", "angular_velocity_y"),
    "wz": ("wz", "gyro_z", "angular_velocity_z"),
    "ax": ("ax", "acc_x", "linear_acceleration_x"),
    "ay": ("ay", "acc_y", "linear_acceleration_y"),
    "az": ("az", "acc_z", "linear_acceleration_z"),
}
PRO_ALIASES = {
    "time": ("time", "t", "timestamp", "stamp"),
    "curL": ("curl", "current_left", "left_current"),
    "curR": ("curr", "current_right", "right_current"),
    "velL": ("vell", "velocity_left", "left_velocity", "speed_left"),
    "velR": ("velr", "velocity_right", "right_velocity", "speed_right"),
}


class BorealTCError(ValueError):
    """A BorealTC folder or file cannot be read (the message names it)."""


@dataclass(frozen=True)
class BorealRun:
    run_id: str
    terrain: str
    pro_path: Path
    imu_path: Path | None


@dataclass
class BorealReport:
    classes: list[str]
    runs: int = 0
    runs_without_imu: list[str] = field(default_factory=list)
    skipped: dict[str, str] = field(default_factory=dict)


def discover(root: str | Path) -> tuple[list[BorealRun], list[str]]:
    """Find runs under ``root``: every ``<CLASS>/pro_XX.csv`` with its ``imu_XX.csv`` if present."""
    root = Path(root)
    if not root.is_dir():
        raise BorealTCError(f"{root}: not a folder (expected <CLASS>/imu_XX.csv and <CLASS>/pro_XX.csv)")
    classes = sorted(d.name for d in root.iterdir() if d.is_dir() and any(d.glob("pro_*.csv")))
    if not classes:
        raise BorealTCError(f"{root}: no <CLASS>/pro_XX.csv files found")
    runs = []
    for cls in classes:
        for pro in sorted((root / cls).glob("pro_*.csv")):
            m = re.fullmatch(r"pro_(\w+)\.csv", pro.name)
            key = m.group(1) if m else pro.stem
            imu = root / cls / f"imu_{key}.csv"
            runs.append(BorealRun(f"{cls}_{key}", cls, pro, imu if imu.is_file() else None))
    return runs, classes


def _read_by_header(path: Path, aliases: dict[str, tuple[str, ...]]) -> pd.DataFrame:
    try:
        raw = pd.read_csv(path)
    except Exception as exc:  # pandas raises several parser errors
        raise BorealTCError(f"{path}: not a readable CSV ({exc})") from None
    lower = {c.strip().lower(): c for c in raw.columns}
    out = {}
    for canon, names in aliases.items():
        found = next((lower[n.lower()] for n in (canon, *names) if n.lower() in lower), None)
        if found is None:
            raise BorealTCError(f"{path}: missing column '{canon}' (have: {', '.join(raw.columns)})")
        out[canon] = pd.to_numeric(raw[found], errors="coerce").to_numpy(dtype=float)
    df = pd.DataFrame(out)
    df = df[np.isfinite(df["time"])].sort_values("time", kind="stable")
    return df.drop_duplicates("time", keep="first").reset_index(drop=True)


def read_imu_csv(path: str | Path) -> pd.DataFrame:
    """IMU file → DataFrame with time (s), wx, wy, wz (rad/s), ax, ay, az (m/s^2)."""
    return _read_by_header(Path(path), IMU_ALIASES)


def read_pro_csv(path: str | Path) -> pd.DataFrame:
    """Proprioception file → DataFrame with time (s), curL, curR (A), velL, velR (m/s)."""
    return _read_by_header(Path(path), PRO_ALIASES)


def _resample(t_src: np.ndarray, values: np.ndarray, t_out: np.ndarray,
              max_gap_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Linear interpolation of (n_src, k) values onto t_out; invalid across gaps > max_gap_s.

    The gap threshold is relative to the *source* period: a 6.5 Hz wheel service is not a gap
    at every 100 Hz tick.
    """
    out = np.column_stack([np.interp(t_out, t_src, values[:, j]) for j in range(values.shape[1])])
    idx = np.searchsorted(t_src, t_out, side="right")
    lo = np.clip(idx - 1, 0, len(t_src) - 1)
    hi = np.clip(idx, 0, len(t_src) - 1)
    gap = t_src[hi] - t_src[lo]
    finite = np.isfinite(values).all(axis=1)
    valid = (t_out >= t_src[0] - 1e-9) & (t_out <= t_src[-1] + 1e-9) & (gap <= max_gap_s) & finite[lo] & finite[hi]
    return out, valid


def run_table(run: BorealRun, classes: list[str], robot: RobotSpec | None = None,
              rate_hz: float = DEFAULT_RATE_HZ) -> pd.DataFrame:
    """Canonical run table (SYSTEM §5) of one BorealTC run at ``rate_hz``."""
    robot = robot or load_robot("husky")
    if robot.n_wheels != 4:
        raise BorealTCError(f"robot spec '{robot.name}': BorealTC needs a four-wheel skid-steer spec")
    pro = read_pro_csv(run.pro_path)
    if len(pro) < 2:
        raise BorealTCError(f"{run.pro_path}: fewer than two samples")
    imu = read_imu_csv(run.imu_path) if run.imu_path is not None else None
    t_end = pro["time"].iloc[-1] if imu is None else min(pro["time"].iloc[-1], imu["time"].iloc[-1])
    t0 = pro["time"].iloc[0] if imu is None else max(pro["time"].iloc[0], imu["time"].iloc[0])
    t = np.arange(t0, t_end + 1e-9, 1.0 / rate_hz)
    if len(t) < 2:
        raise BorealTCError(f"{run.pro_path}: IMU and wheel files do not overlap in time")
    pro_period = float(np.median(np.diff(pro["time"])))
    pv, pvalid = _resample(pro["time"].to_numpy(), pro[["curL", "curR", "velL", "velR"]].to_numpy(),
                           t, 2.5 * pro_period)
    d: dict[str, np.ndarray] = {"t_s": t - t[0]}
    side = {1: 0, 2: 1, 3: 0, 4: 1}  # wheel -> left(0)/right(1)
    for i in range(1, 5):
        d[f"wheel{i}_omega_radps"] = pv[:, 2 + side[i]] / robot.wheel_radius_m
        d[f"wheel{i}_steer_rad"] = np.zeros(len(t))
        d[f"wheel{i}_current_a"] = pv[:, side[i]]
    if imu is not None:
        imu_period = float(np.median(np.diff(imu["time"])))
        iv, ivalid = _resample(imu["time"].to_numpy(), imu[["ax", "ay", "az", "wx", "wy", "wz"]].to_numpy(),
                               t, 2.5 * imu_period)
    else:
        iv, ivalid = np.full((len(t), 6), np.nan), np.zeros(len(t), bool)
    for j, name in enumerate(("imu_ax_mps2", "imu_ay_mps2", "imu_az_mps2", "imu_roll_rate_radps",
                              "imu_pitch_rate_radps", "imu_yaw_rate_radps")):
        d[name] = iv[:, j]
    d["wheels_valid"] = pvalid
    d["steer_valid"] = np.ones(len(t), bool)
    d["current_valid"] = pvalid
    d["imu_valid"] = ivalid
    d["cam_valid"] = np.zeros(len(t), bool)
    d["cmd_valid"] = np.zeros(len(t), bool)
    d["terrain"] = np.full(len(t), classes.index(run.terrain), dtype=np.int64)
    d["run_id"] = np.full(len(t), run.run_id, dtype=object)
    df = validate_run_table(pd.DataFrame(d), robot.n_wheels, source=str(run.pro_path))
    df.attrs["terrainml"] = make_metadata(
        robot_json=robot.to_json(), source_file=str(run.pro_path), rate_hz=rate_hz,
        dataset="borealtc", classes=list(classes), imu_file=str(run.imu_path) if run.imu_path else None)
    return df


def load_borealtc(root: str | Path, robot: RobotSpec | None = None, rate_hz: float = DEFAULT_RATE_HZ,
                  require_imu: bool = False) -> tuple[list[pd.DataFrame], BorealReport]:
    """Read every run of a BorealTC folder into canonical run tables.

    Parameters
    ----------
    require_imu : if True, runs without an IMU file are skipped (and counted); otherwise they are
        kept with wheel channels only.
    """
    runs, classes = discover(root)
    report = BorealReport(classes=classes)
    tables = []
    for run in runs:
        if run.imu_path is None:
            report.runs_without_imu.append(run.run_id)
            if require_imu:
                report.skipped[run.run_id] = "IMU file missing"
                continue
        try:
            tables.append(run_table(run, classes, robot, rate_hz))
        except BorealTCError as exc:
            report.skipped[run.run_id] = str(exc)
    report.runs = len(tables)
    return tables, report
