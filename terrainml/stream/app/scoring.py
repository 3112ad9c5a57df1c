"""Replay samples through the predictor and score what it served, tick by tick.

:func:`replay_served` is the one replay: every sample through :meth:`Predictor.step`, each tick's
served class, fallback reason, label and odometer kept (:class:`ServedTicks`). Two readers score it:

* :func:`score_served` -- the served-path figures of ``terrainml train``'s held-out replay
  (:func:`terrainml.pipeline.replay.replay_course`): shares of moving labelled ticks served right,
  served a fallback, served a class; classifications per metre; distance to the first right tick
  after a label change;
* :func:`replay_summary` -- ``make demo``'s table: consecutive ticks serving one class with one
  fallback reason form a segment.

A tick is *moving* when the predictor's odometer advanced at >= :data:`MOVING_TICK_MPS` since the
tick before (the EKF's body speed, integrated over healthy ticks). An unhealthy tick
(``estimator_unhealthy``: a sensor group the model needs is silent or flagged invalid) adds no
distance, since its speed is not trusted; it is moving when the mean rim speed of its valid
wheels is at least that line, so the ticks a robot under way loses to an unhealthy estimator are
scored (as fallbacks), not left out. Only moving labelled ticks that were served a message are
scored. A fallback tick is never right.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np
from rich.console import Console
from rich.table import Table

from terrainml.robot import RobotSpec
from terrainml.schema import wheel_col
from terrainml.stream.app.options import CLASSIFY_LAG_TICKS
from terrainml.stream.tick.config import ServingConfig
from terrainml.stream.tick.message import ESTIMATOR_UNHEALTHY, DesiredSlip
from terrainml.stream.tick.predictor import Predictor
from terrainml.stream.tick.sample import NO_SAMPLE, InvalidSample, Sample
from terrainml.stream.transports.sources import open_source

__all__ = ["MOVING_TICK_MPS", "NO_MESSAGE", "FALLBACK", "ServedTicks", "replay_served",
           "moving_ticks", "ticks_moving", "label_changes", "after_changes", "score_served", "replay_summary"]

#: a served tick is scored when the robot's body moved at least this fast since the tick before,
#: m/s: any tick of a robot under way counts. The novelty gate's line
#: (:data:`terrainml.models.novelty.MOVING_MPS`, 0.2 m/s) is another quantity: the mean wheel rim
#: speed of a whole window, below which its features cannot tell ground apart
MOVING_TICK_MPS = 0.05
#: ``ServedTicks.served`` of a sample that gave no message (dropped by the clock policy, invalid)
NO_MESSAGE = -2
#: ``ServedTicks.served`` of a tick served a fallback (no class)
FALLBACK = -1


@dataclass(frozen=True)
class ServedTicks:
    """What the predictor served on each sample of a replay (n samples).

    Attributes
    ----------
    t_s : float (n,), s, the sample's time.
    label : int (n,), the sample's logged ``terrain`` class id; -1 when it has none.
    served : int (n,), the served class id; :data:`FALLBACK` or :data:`NO_MESSAGE`.
    odometer_m : float (n,), m, the predictor's odometer after the sample.
    reasons : str (n,), the message's fallback reason ("" when none or no message).
    messages : the messages, None where a sample gave none.
    stats : the predictor's end-of-replay counters (:meth:`Predictor.stats`).
    class_names : the served class names by class id.
    rim_speed_mps : float (n,), m/s, the mean |rim speed| of the sample's valid wheels (NaN when
        none is valid, or not recorded).
    """

    t_s: np.ndarray
    label: np.ndarray
    served: np.ndarray
    odometer_m: np.ndarray
    reasons: list[str]
    messages: list[DesiredSlip | None]
    stats: dict[str, Any]
    class_names: list[str]
    rim_speed_mps: np.ndarray | None = None


def _label_of(sample: Sample) -> int:
    """The sample's ``terrain`` class id, -1 for none, NaN or negative."""
    lab = sample.columns.get("terrain")
    try:
        return int(lab) if lab is not None and lab == lab and int(lab) >= 0 else -1
    except (TypeError, ValueError):
        return -1


def replay_served(predictor: Predictor, samples: Iterable[Any]) -> ServedTicks:
    """Serve every sample through ``predictor`` (closed at the end); what it served on each.

    A sample the predictor refuses (:class:`InvalidSample`, counted in its counters) is a tick
    without a message, at time NaN and without a label.
    """
    t_s, label, served, odo, reasons, messages, rim = [], [], [], [], [], [], []
    omega = [wheel_col("omega", i) for i in range(1, predictor.robot.n_wheels + 1)]
    radius_m = float(predictor.robot.wheel_radius_m)
    try:
        for raw in samples:
            try:
                sample = predictor.accept(raw)
            except InvalidSample:
                sample = NO_SAMPLE
            msg = None if sample is NO_SAMPLE else predictor.step(sample)
            t_s.append(sample.t_s)
            label.append(_label_of(sample))
            odo.append(predictor.odometer_m)
            rim.append(_rim_speed_mps(sample, omega, radius_m))
            messages.append(msg)
            if msg is None:
                served.append(NO_MESSAGE)
                reasons.append("")
            else:
                served.append(FALLBACK if msg.fallback else int(msg.terrain_class))
                reasons.append(msg.fallback_reason)
    finally:
        predictor.close()
    return ServedTicks(np.asarray(t_s, dtype=float), np.asarray(label, dtype=np.int64),
                       np.asarray(served, dtype=np.int64), np.asarray(odo, dtype=float), reasons, messages,
                       predictor.stats(), list(predictor.class_names), np.asarray(rim, dtype=float))


def _rim_speed_mps(sample: Sample, omega: list[str], radius_m: float) -> float:
    """Mean |omega| R over the sample's finite wheel speeds, m/s (NaN: none)."""
    if sample is NO_SAMPLE:
        return float("nan")
    w = [abs(float(v)) for c in omega if isinstance(v := sample.columns.get(c), (int, float)) and math.isfinite(v)]
    return float(np.mean(w)) * radius_m if w else float("nan")


def moving_ticks(t_s: np.ndarray, label: np.ndarray, served: np.ndarray, odometer_m: np.ndarray,
                 reasons: Sequence[str] | None = None, rim_speed_mps: np.ndarray | None = None) -> np.ndarray:
    """Bool (n,): labelled ticks served a message whose odometer speed since the tick before is
    >= :data:`MOVING_TICK_MPS` (the first tick has no speed); given ``reasons`` and
    ``rim_speed_mps`` (n,), also the ``estimator_unhealthy`` ticks whose rim speed is (module
    docstring)."""
    dt = np.diff(t_s, prepend=t_s[0])
    speed = np.divide(np.diff(odometer_m, prepend=odometer_m[0]), dt, out=np.zeros_like(dt), where=dt > 0)
    moving = speed >= MOVING_TICK_MPS
    if reasons is not None and rim_speed_mps is not None:
        unhealthy = np.array([r == ESTIMATOR_UNHEALTHY for r in reasons], dtype=bool)
        moving |= unhealthy & (np.nan_to_num(rim_speed_mps, nan=0.0) >= MOVING_TICK_MPS)
    return moving & (label >= 0) & (served != NO_MESSAGE)


def ticks_moving(ticks: ServedTicks) -> np.ndarray:
    """:func:`moving_ticks` of a replay's ticks."""
    return moving_ticks(ticks.t_s, ticks.label, ticks.served, ticks.odometer_m, ticks.reasons, ticks.rim_speed_mps)


def label_changes(label: np.ndarray) -> np.ndarray:
    """Indices (k,) of the ticks whose labelled class differs from the tick before's."""
    return np.flatnonzero((label[1:] != label[:-1]) & (label[1:] >= 0)) + 1


def after_changes(t_s: np.ndarray, label: np.ndarray, settle_s: float) -> np.ndarray:
    """Bool (n,): ticks within ``settle_s`` s after a change of the labelled class."""
    out = np.zeros(len(t_s), bool)
    for tc in t_s[label_changes(label)]:
        out |= (t_s >= tc) & (t_s < tc + settle_s)
    return out


def score_served(t, lab, served, odo, reasons, settle_s: float, st: dict, rim_speed_mps=None) -> dict[str, Any]:
    """The served-path figures of one replay (:func:`terrainml.pipeline.replay.replay_course`).

    Parameters
    ----------
    t, lab, served, odo, reasons : per tick (n,): time s, label, served class, odometer m,
        fallback reason (:class:`ServedTicks`' fields).
    settle_s : s after each label change left out of ``right_share_settled``.
    st : the predictor's counters (``classifications``, ``distance_m``, ``member_ticks``: ticks
        served by the model and by each of its sensor members, when it has members).
    rim_speed_mps : per tick (n,) or None, m/s: which unhealthy ticks move (:func:`moving_ticks`).
    """
    moving = moving_ticks(t, lab, served, odo, reasons, rim_speed_mps)
    right = served == lab
    change = label_changes(lab)
    settled = ~after_changes(t, lab, settle_s)
    dists, never = [], 0
    bounds = list(change) + [len(t)]
    for a, b in zip(bounds[:-1], bounds[1:]):
        hit = np.flatnonzero(right[a:b])
        if len(hit):
            dists.append(float(odo[a + hit[0]] - odo[a]))
        else:
            never += 1
    n_mov = int(moving.sum())

    def share(m):
        return (float(m.sum() / n_mov) if n_mov else float("nan"))
    fb = moving & (served == FALLBACK)
    mov_set = moving & settled
    dist = float(st.get("distance_m", odo[-1] if len(odo) else 0.0))
    return {"ticks": int(len(t)), "moving_ticks": n_mov, "right_share": share(moving & right),
            "right_share_settled": float((mov_set & right).sum() / mov_set.sum()) if mov_set.any() else float("nan"),
            "fallback_share": share(fb), "classified_share": share(moving & (served >= 0)),
            "classifications": int(st.get("classifications", 0)), "distance_m": dist,
            "classifications_per_m": float(st.get("classifications", 0) / dist) if dist > 0 else float("nan"),
            "changes": int(len(change)), "median_change_m": float(np.median(dists)) if dists else float("nan"),
            "changes_never_right": int(never),
            "member_ticks": {str(k): int(v) for k, v in (st.get("member_ticks") or {}).items()},
            "fallback_reasons": {r: int(sum(1 for i in np.flatnonzero(fb) if reasons[i] == r))
                                 for r in sorted({reasons[i] for i in np.flatnonzero(fb)})}}


def replay_summary(model: str | Path, log_path: str | Path, *, console: Console | None = None,
                   robot: RobotSpec | None = None,
                   on_ticks: Callable[[ServedTicks], None] | None = None) -> list[dict[str, Any]]:
    """Replay a recorded log through the predictor and print what it served (for ``make demo``).

    Consecutive ticks serving the same class with the same fallback reason form one segment;
    returns the segments as dicts (``t_start_s``, ``t_end_s``, ``terrain_class``,
    ``terrain_name``, ``fallback_reason``, ``ticks``, ``mean_slip_desired``, ``true_class``,
    the most frequent logged ``terrain`` label of the segment when the log has labels, and
    ``moving_ticks`` / ``moving_right``: moving labelled ticks (:func:`moving_ticks`) and those
    of them that served the logged class (a fallback tick is never right)). ``on_ticks`` is given
    the replay's :class:`ServedTicks` (e.g. to say where the moving ticks went).
    """
    console = console or Console(stderr=True, soft_wrap=True)
    predictor = Predictor.from_model_dir(
        model, robot=robot, config=ServingConfig(classify_lag_ticks=CLASSIFY_LAG_TICKS))
    ticks = replay_served(predictor, open_source(str(log_path), robot=predictor.robot))
    segments = _segments(ticks)
    if on_ticks is not None:
        on_ticks(ticks)
    table = Table(title=f"served by {Path(model).name} on {Path(log_path).name}")
    for col in ("t (s)", "served class", "fallback", "mean desired slip", "logged class"):
        table.add_column(col)
    for seg in segments:
        table.add_row(f"{seg['t_start_s']:.2f}-{seg['t_end_s']:.2f}", seg["terrain_name"],
                      seg["fallback_reason"] or "-",
                      " ".join(f"{v:+.3f}" for v in seg["mean_slip_desired"]),
                      "-" if seg["true_class"] is None else _label_name(seg["true_class"], ticks.class_names))
    console.print(table)
    return segments


def _segments(ticks: ServedTicks) -> list[dict[str, Any]]:
    """Runs of served messages with one class and one fallback reason (:func:`replay_summary`)."""
    moving = ticks_moving(ticks)
    segments: list[dict[str, Any]] = []
    labels: list[int] = []
    for i, msg in enumerate(ticks.messages):
        if msg is None:
            continue
        key = (msg.terrain_class, msg.fallback_reason)
        if not segments or segments[-1]["_key"] != key:
            if segments:
                _close_segment(segments[-1], labels)
            segments.append({"_key": key, "t_start_s": msg.t_s, "terrain_class": msg.terrain_class,
                             "terrain_name": msg.terrain_name, "fallback_reason": msg.fallback_reason,
                             "ticks": 0, "moving_ticks": 0, "moving_right": 0,
                             "_slip": np.zeros(len(msg.slip_desired))})
            labels = []
        seg = segments[-1]
        seg["t_end_s"] = msg.t_s
        seg["ticks"] += 1
        seg["_slip"] += np.asarray(msg.slip_desired)
        lab = int(ticks.label[i])
        if lab >= 0:
            labels.append(lab)
        if moving[i]:
            seg["moving_ticks"] += 1
            seg["moving_right"] += int(ticks.served[i] == lab)
    if segments:
        _close_segment(segments[-1], labels)
    return segments


def _label_name(cid: int, names: Sequence[str]) -> str:
    """A logged class id by name (the model's names by id), the id itself where it has none."""
    return names[cid] if 0 <= cid < len(names) else str(cid)


def _close_segment(seg: dict[str, Any], labels: list[int]) -> None:
    seg["mean_slip_desired"] = [float(v) for v in seg.pop("_slip") / max(seg["ticks"], 1)]
    seg.pop("_key", None)
    seg["true_class"] = Counter(labels).most_common(1)[0][0] if labels else None
