"""Fixed chunks and the windows inside them: the BorealTC authors' windows, for any robot (design §8).

The ``chunks`` window spec (:data:`terrainml.features.windows.WINDOW_SPECS`): every run is cut into
non-overlapping ``chunk_s`` chunks from its first row (:func:`make_chunks`; a chunk with an invalid
or unlabelled row is dropped and counted), and ``window_s`` windows are cut inside every chunk
(:func:`chunk_windows`, windows never cross a chunk boundary). ``homogeneous=True`` reproduces the
authors' class balancing ("homogeneous augmentation", LaRocque et al., IROS 2024): the class with
the fewest chunks gets ``max_windows_per_chunk`` windows per chunk, every other class
``int(max_windows_per_chunk * n_min / n_k)``, evenly spaced, so every class has about the same
number of windows (:func:`windows_per_chunk`). The BorealTC protocols
(:mod:`terrainml.experiments.borealtc`) and ``terrainml dataset build --windows chunks``
(:mod:`terrainml.pipeline.dataset`) both call these functions, so both see the same windows.

The dataset builder's chunked mode lives here too: :func:`chunk_source` keeps the columns a run
contributes, and :func:`cut_chunked_runs` cuts the windows of all runs at once (the class
balancing needs every run) and counts, per run, the chunks each rule dropped. A spec is chunked
when it has a ``chunk_s`` (:attr:`terrainml.features.windows.WindowSpec.chunk_s`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import pandas as pd

from terrainml.features.windows import RULES, Windows, WindowSpec, channel_column, channel_sensor_group
from terrainml.robot import RobotSpec

__all__ = ["SIDE_CHANNELS", "VALID_COLUMNS", "ChunkSet", "make_chunks", "windows_per_chunk",
           "chunk_windows", "radius_from_tables", "side_channel_columns", "needs_estimation",
           "chunk_source", "cut_chunked_runs"]

#: raw channels of a skid-steer robot without camera: window channel name -> run-table column.
#: ``current_left``/``speed_left_mps`` come from wheel 1 (front-left; the Husky's left motor drives
#: wheels 1 and 3), the right side from wheel 2. Speeds are wheel rim speeds omega * R (m/s).
SIDE_CHANNELS: dict[str, str] = {
    "imu_ax": "imu_ax_mps2", "imu_ay": "imu_ay_mps2", "imu_az": "imu_az_mps2",
    "imu_wx": "imu_roll_rate_radps", "imu_wy": "imu_pitch_rate_radps", "imu_wz": "imu_yaw_rate_radps",
    "current_left": "wheel1_current_a", "current_right": "wheel2_current_a",
    "speed_left_mps": "wheel1_omega_radps", "speed_right_mps": "wheel2_omega_radps",
}
VALID_COLUMNS = ("imu_valid", "wheels_valid", "current_valid")


# ------------------------------------------------------------------------------------ chunks
@dataclass
class ChunkSet:
    """Non-overlapping chunks of the runs.

    Attributes
    ----------
    meta : DataFrame, one row per chunk: ``chunk_id`` (int, 0..m-1), ``run_id`` (str),
        ``terrain`` (int label), ``table`` (index into the tables list), ``start_index`` (row),
        ``t_start_s`` (s).
    chunk_samples : int, rows per chunk.
    rate_hz : float.
    dropped : dict reason -> number of chunks (or runs) left out.
    runs_without_chunks : list of run ids that gave no chunk (e.g. no IMU file).
    """

    meta: pd.DataFrame
    chunk_samples: int
    rate_hz: float
    dropped: dict = field(default_factory=dict)
    runs_without_chunks: list = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.meta)


def _table_rate_hz(df: pd.DataFrame) -> float:
    rate = (df.attrs.get("terrainml") or {}).get("rate_hz")
    if rate:
        return float(rate)
    return float(1.0 / np.median(np.diff(df["t_s"].to_numpy())))


def make_chunks(tables: Sequence[pd.DataFrame], chunk_s: float = 5.0,
                valid_cols: Sequence[str] = VALID_COLUMNS) -> ChunkSet:
    """Cut every run table into non-overlapping ``chunk_s`` chunks from its first row.

    Parameters
    ----------
    tables : canonical run tables (one run each; ``terrain`` int label, ``run_id``), same rate.
    chunk_s : chunk length in seconds (5 s in the authors' protocol).
    valid_cols : validity flags that must all be True on every row of a chunk; a chunk with an
        invalid row is dropped and counted (a run without IMU therefore yields no chunk).

    Returns
    -------
    ChunkSet
    """
    if not tables:
        raise ValueError("make_chunks: no run tables")
    if not chunk_s > 0:
        raise ValueError(f"make_chunks: chunk_s must be > 0, got {chunk_s!r}")
    rate = _table_rate_hz(tables[0])
    L = int(round(chunk_s * rate))
    rows, dropped, empty = [], {"invalid samples": 0, "unlabelled": 0}, []
    for k, df in enumerate(tables):
        run_id = str(df["run_id"].iloc[0])
        n = len(df)
        ok = np.ones(n, bool)
        for c in valid_cols:
            if c in df:
                ok &= df[c].to_numpy(dtype=bool)
        labels = df["terrain"].to_numpy()
        n_before = len(rows)
        for s in range(0, n - L + 1, L):
            if not ok[s:s + L].all():
                dropped["invalid samples"] += 1
                continue
            lab = labels[s:s + L]
            if lab[0] < 0 or (lab != lab[0]).any():
                dropped["unlabelled"] += 1
                continue
            rows.append((run_id, int(lab[0]), k, s, float(df["t_s"].iloc[s])))
        if len(rows) == n_before:
            empty.append(run_id)
    meta = pd.DataFrame(rows, columns=["run_id", "terrain", "table", "start_index", "t_start_s"])
    meta.insert(0, "chunk_id", np.arange(len(meta), dtype=np.int64))
    return ChunkSet(meta, L, rate, dropped, empty)


def windows_per_chunk(chunk_terrain: np.ndarray, max_windows_per_chunk: int,
                      homogeneous: bool = True) -> dict[int, int]:
    """Windows cut from each chunk of a class (the authors' homogeneous augmentation).

    The class with the fewest chunks gets ``max_windows_per_chunk``; class k gets
    ``int(max_windows_per_chunk * n_min / n_k)`` (at least 1) so every class has about
    ``max_windows_per_chunk * n_min`` windows. ``homogeneous=False``: every class gets the max.
    """
    labels, counts = np.unique(np.asarray(chunk_terrain), return_counts=True)
    if not homogeneous:
        return {int(c): int(max_windows_per_chunk) for c in labels}
    n_min = counts.min()
    return {int(c): max(1, int(max_windows_per_chunk * n_min / n)) for c, n in zip(labels, counts)}


def chunk_windows(tables: Sequence[pd.DataFrame], chunks: ChunkSet, window_s: float = 1.7,
                  max_windows_per_chunk: int = 33, homogeneous: bool = True,
                  channels: dict[str, str] | None = None, wheel_radius_m: float | None = None) -> Windows:
    """Cut ``window_s`` windows inside every chunk (windows never cross a chunk boundary).

    Parameters
    ----------
    tables : the run tables the chunks were cut from.
    chunks : :func:`make_chunks` output.
    window_s : window length (s); 1.7 s in the authors' headline numbers.
    max_windows_per_chunk : windows per chunk of the smallest class (33 = the authors' 0.1-s
        stride in a 5-s chunk with 1.7-s windows). Starts are evenly spaced with the
        integer stride ``(chunk - window) // n_k`` from the chunk start, as in the authors' code.
    homogeneous : balance the classes (see :func:`windows_per_chunk`).
    channels : window channel name -> run-table column (default :data:`SIDE_CHANNELS`).
    wheel_radius_m : R to turn ``*_omega_radps`` into rim speed for channels named
        ``speed_*_mps`` (default: the robot spec in the table metadata, else 1).

    Returns
    -------
    Windows with X (n, C, T) and meta columns ``run_id, terrain, chunk_id, t_start_s, t_end_s,
    start_index``.
    """
    channels = dict(channels or SIDE_CHANNELS)
    T = int(round(window_s * chunks.rate_hz))
    L = chunks.chunk_samples
    if T > L:
        raise ValueError(f"chunk_windows: window {window_s} s longer than the chunk ({L} samples)")
    if max_windows_per_chunk < 1:
        raise ValueError("chunk_windows: max_windows_per_chunk must be >= 1")
    if wheel_radius_m is None:
        wheel_radius_m = radius_from_tables(tables)
    per = windows_per_chunk(chunks.meta["terrain"].to_numpy(), max_windows_per_chunk, homogeneous)
    names = list(channels)
    # per table, the channel matrix (C, n) in window units
    mats: dict[int, np.ndarray] = {}
    for k in np.unique(chunks.meta["table"].to_numpy()):
        df = tables[int(k)]
        cols = []
        for name, col in channels.items():
            if col not in df:
                raise KeyError(f"run {df['run_id'].iloc[0]}: column {col!r} (channel {name}) missing")
            x = df[col].to_numpy(dtype=np.float64)
            if name.startswith("speed_") and col.endswith("_omega_radps"):
                x = x * wheel_radius_m
            cols.append(x)
        mats[int(k)] = np.stack(cols)
    X, meta = [], []
    for ch in chunks.meta.itertuples(index=False):
        n_k = per[int(ch.terrain)]
        stride = max(1, (L - T) // n_k) if n_k > 1 else 0
        M = mats[int(ch.table)]
        t0 = float(tables[int(ch.table)]["t_s"].iloc[ch.start_index])
        for j in range(n_k):
            s = int(ch.start_index) + j * stride
            if s + T > int(ch.start_index) + L:
                break
            X.append(M[:, s:s + T])
            meta.append((ch.run_id, int(ch.terrain), int(ch.chunk_id), t0 + j * stride / chunks.rate_hz,
                         t0 + (j * stride + T) / chunks.rate_hz, s))
    meta_df = pd.DataFrame(meta, columns=["run_id", "terrain", "chunk_id", "t_start_s", "t_end_s", "start_index"])
    Xa = np.stack(X) if X else np.zeros((0, len(names), T))
    return Windows(Xa, tuple(names), meta_df, chunks.rate_hz)


def radius_from_tables(tables) -> float:
    md = tables[0].attrs.get("terrainml") or {}
    rj = md.get("robot_spec") or md.get("robot_json")
    if rj:
        try:
            d = json.loads(rj) if isinstance(rj, str) else rj
            return float(d["wheel_radius_m"])
        except (ValueError, KeyError, TypeError):
            pass
    return 1.0


def side_channel_columns(channels: Sequence[str], robot) -> dict[str, str]:
    """Run-table column of each side channel for ``robot`` (its first left/right wheel)."""
    return {c: channel_column(c, robot)[0] for c in channels}


# ------------------------------------------------------------------------------------ dataset mode
def needs_estimation(channels: Sequence[str]) -> bool:
    """True when a channel comes from the EKF (body velocity) or the camera (slip)."""
    return any(channel_sensor_group(c) in ("estimator", "cam") for c in channels)


def chunk_source(src: pd.DataFrame, table: pd.DataFrame, robot: RobotSpec, channels: Sequence[str]) -> pd.DataFrame:
    """The columns of one run that the chunked mode cuts: time, run id, label, channels and validity.

    Parameters
    ----------
    src : the run's EST table when :func:`needs_estimation` (``channels``), else ``table``.
    table : the canonical run table (run id and base rate when ``src`` lacks them).
    robot : RobotSpec (the side channels' wheels). channels : the spec's window channels.
    """
    cols = ["t_s", "run_id", "terrain"]
    for ch in channels:
        col, vcols, _ = channel_column(ch, robot)
        cols += [col, *vcols]
    out = pd.DataFrame({c: src[c].to_numpy() for c in dict.fromkeys(cols) if c in src.columns})
    if "run_id" not in out.columns:
        out["run_id"] = str(table["run_id"].iloc[0]) if "run_id" in table.columns else ""
    if "terrain" not in out.columns:
        out["terrain"] = -1
    out.attrs["terrainml"] = {"rate_hz": (table.attrs.get("terrainml") or {}).get("rate_hz")}
    return out


def cut_chunked_runs(tables: Sequence[pd.DataFrame], run_ids: Sequence[str], robot: RobotSpec,
                     spec: WindowSpec) -> list[tuple[Windows, dict]]:
    """Windows and rejection counts of every run, cut over all runs at once (chunked spec).

    Parameters
    ----------
    tables : :func:`chunk_source` tables, one per run (non-empty). run_ids : their run ids.
    robot : RobotSpec. spec : the resolved chunked spec (``channels`` set).

    Returns
    -------
    One ``(windows, counts)`` per table: the run's windows (meta without ``chunk_id``) and counts
    whose ``n_windows`` are its chunks, ``n_rejected`` the chunks dropped (``channel_valid``: an
    invalid sample; ``terrain_label``: a missing or changing label).
    """
    channels = spec.channels_for(robot)
    valid_cols = sorted({v for ch in channels for v in channel_column(ch, robot)[1]})
    chunks = make_chunks(tables, chunk_s=float(spec.chunk_s), valid_cols=valid_cols)
    cols = {ch: channel_column(ch, robot)[0] for ch in channels}
    if len(chunks):
        wins = chunk_windows(tables, chunks, window_s=spec.window_s, max_windows_per_chunk=spec.windows_per_chunk,
                             homogeneous=spec.homogeneous, channels=cols, wheel_radius_m=robot.wheel_radius_m)
    else:
        wins = Windows.concat([], channels=channels, n_samples=spec.n_samples, rate_hz=spec.rate_hz)
    L = chunks.chunk_samples
    run_of_window = wins.meta["run_id"].astype(str).to_numpy() if len(wins) else np.array([], dtype=object)
    kept_chunks = chunks.meta.groupby("table").size().to_dict() if len(chunks) else {}
    out = []
    for k, (table, run_id) in enumerate(zip(tables, run_ids)):
        w = wins.subset(np.flatnonzero(run_of_window == str(run_id)))
        w.meta = w.meta.drop(columns=["chunk_id"], errors="ignore")
        n_chunks = len(table) // L
        lost = n_chunks - int(kept_chunks.get(k, 0))
        counts = {"n_windows": int(n_chunks), "n_kept": int(len(w)), "n_rejected": int(lost)}
        counts.update({rule: 0 for rule in RULES})
        invalid = min(_invalid_chunks(table, L, valid_cols), lost)
        counts["channel_valid"] = int(invalid)
        counts["terrain_label"] = int(lost - invalid)
        counts["unlabelled"] = 0
        out.append((w, counts))
    return out


def _invalid_chunks(df: pd.DataFrame, L: int, valid_cols) -> int:
    """Chunks of ``L`` rows of ``df`` with an invalid row (any of ``valid_cols`` false)."""
    ok = np.ones(len(df), bool)
    for c in valid_cols:
        if c in df.columns:
            ok &= df[c].to_numpy(dtype=bool)
    n = len(df) // L
    return int(sum(not ok[s * L:(s + 1) * L].all() for s in range(n)))
