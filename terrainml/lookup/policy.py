"""Serving policy: which class's targets to serve, fallback, per-wheel sign (design §10).

Per-wheel sign logic (thesis eq. 8.7-8.9)::

    s_des_i = sgn(v_long_i) * s_target(class, state_i)      state_i in traction|braking|steady
    s_des_i = 0                                              state_i == idle (or v_long_i == 0)

``s_target(class, "braking")`` is negative (the braking branch), so forward braking asks for
negative slip and backward braking for positive slip, exactly as thesis Table 8.1.

Probability-aware policy (:func:`choose`), with class probabilities p:

1. **fallback** to the least aggressive row (``pavement`` when the table has it), with
   ``fallback=True`` and a reason, when the estimator is unhealthy (``"estimator_unhealthy"``,
   checked first), no classification exists yet (``"no_classification"``), or the last one is
   older than ``max_age_s`` = 1.0 s (``"stale_classification"``);
2. **confident**: max p >= 0.6 -> the argmax class;
3. **uncertain**: otherwise the least aggressive class among those with p >= 0.1 (the argmax
   alone if none reaches 0.1). "Least aggressive" = smallest traction-target magnitude, ties
   broken by the smaller steady and then braking magnitude (:meth:`DesiredSlipTable.
   aggressiveness_order`). One class is served for all wheels so the message names one class.

The class-free **safe cap** of design §10 (:meth:`DesiredSlipTable.safe_cap`; per wheel with
:func:`safe_cap_per_wheel`) is the fallback the design asks for: the largest traction target
(traction and steady) and the most negative braking target of the table's classes. ``choose``
still serves the least aggressive row on fallback until the stream switches to it (issue #19).

These functions are cheap (a few microseconds): they run on every 10 ms tick.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Protocol, Sequence

import numpy as np

from terrainml.classes import TERRAIN_CLASSES

__all__ = ["CANDIDATE_P", "CONFIDENT_P", "MAX_AGE_S", "PolicyDecision", "choose",
           "desired_slip_per_wheel", "fallback_class_id", "least_aggressive",
           "safe_cap_per_wheel"]

CONFIDENT_P = 0.6   # design §10: serve the argmax at or above this probability
CANDIDATE_P = 0.1   # design §10: classes considered when uncertain
MAX_AGE_S = 1.0     # design §10: older classifications are stale
FALLBACK_NAME = "pavement"
_ACTIVE_STATES = ("steady", "traction", "braking")


class TargetTable(Protocol):
    """What the policy needs from a table (:class:`terrainml.lookup.table.DesiredSlipTable`)."""

    def target(self, class_id: int, state: str) -> float: ...


@dataclass(frozen=True)
class PolicyDecision:
    """Result of :func:`choose`.

    Attributes
    ----------
    class_id, class_name : the class whose targets are served.
    confidence : probability of the served class (0.0 on fallback).
    slip_desired : tuple of N floats, signed per-wheel desired slip (empty when ``choose`` was
        not given wheel states).
    fallback : True when the fallback row is served.
    reason : "" or one of ``estimator_unhealthy``, ``no_classification``,
        ``stale_classification``.
    """

    class_id: int
    class_name: str
    confidence: float
    slip_desired: tuple[float, ...]
    fallback: bool
    reason: str


def _table_class_ids(table: Any) -> list[int]:
    ids = getattr(table, "class_ids", None)
    if ids is not None:
        return [int(c) for c in ids]
    return list(range(len(TERRAIN_CLASSES)))


def _name(table: Any, cid: int) -> str:
    fn = getattr(table, "class_name", None)
    if callable(fn):
        return str(fn(cid))
    return TERRAIN_CLASSES[cid] if 0 <= cid < len(TERRAIN_CLASSES) else str(cid)


def _aggressiveness(table: Any, cid: int) -> tuple[float, float, float]:
    return (abs(float(table.target(cid, "traction"))), abs(float(table.target(cid, "steady"))),
            abs(float(table.target(cid, "braking"))))


def least_aggressive(table: Any, candidates: Sequence[int]) -> int:
    """Candidate class with the smallest (|traction|, |steady|, |braking|) targets."""
    rank = getattr(table, "aggressiveness_rank", None)
    if callable(rank):
        return min((int(c) for c in candidates), key=rank)
    return min((int(c) for c in candidates), key=lambda c: _aggressiveness(table, c))


def fallback_class_id(table: Any) -> int:
    """The fallback row: ``pavement`` when the table has it, else its least aggressive row."""
    cached = getattr(table, "fallback_class_id", None)
    if isinstance(cached, int):
        return cached
    ids = _table_class_ids(table)
    for c in ids:
        if _name(table, c) == FALLBACK_NAME:
            return c
    return least_aggressive(table, ids)


def desired_slip_per_wheel(class_id: int, states: Sequence[str], v_long: Sequence[float],
                           table: TargetTable) -> list[float]:
    """Signed desired slip per wheel, eq. 8.7-8.9.

    Parameters
    ----------
    class_id : served class.
    states : N dynamic states (``idle|steady|traction|braking``, design §7.2).
    v_long : N wheel-centre longitudinal speeds, m/s (only the sign is used).
    table : anything with ``target(class_id, state)``.

    Returns
    -------
    list of N floats: ``sgn(v_long_i) * target(class_id, state_i)``; 0.0 for idle wheels and
    for a zero or non-finite ``v_long_i``; unknown states raise ValueError.
    """
    return _signed_per_wheel(states, v_long, lambda st: table.target(class_id, st))


def safe_cap_per_wheel(states: Sequence[str], v_long: Sequence[float], table: Any,
                       classes: Sequence[str] | None = None) -> list[float]:
    """Signed class-free safe cap per wheel (design §10), with the sign logic of eq. 8.7-8.9.

    Parameters
    ----------
    states, v_long : as :func:`desired_slip_per_wheel`.
    table : a :class:`terrainml.lookup.table.DesiredSlipTable` (its ``safe_cap``).
    classes : optional class names the cap is taken over (default all the table's classes).

    Returns
    -------
    list of N floats: ``sgn(v_long_i) * cap(state_i)``, cap = max s_T in traction and steady,
    min s_B in braking; 0.0 for idle or zero/non-finite speed.
    """
    cap = table.safe_cap(classes)
    return _signed_per_wheel(states, v_long, cap.target)


def _signed_per_wheel(states: Sequence[str], v_long: Sequence[float],
                      target: Callable[[str], float]) -> list[float]:
    """eq. 8.7-8.9 for any per-state target: sgn(v) * target(state), 0 when idle or v = 0."""
    if len(states) != len(v_long):
        raise ValueError(f"states ({len(states)}) and v_long ({len(v_long)}) differ in length")
    out: list[float] = []
    for st, v in zip(states, v_long):
        v = float(v)
        if st == "idle" or not math.isfinite(v) or v == 0.0:
            out.append(0.0)
        elif st in _ACTIVE_STATES:
            out.append(math.copysign(1.0, v) * float(target(st)))
        else:
            raise ValueError(f"unknown wheel state {st!r}; expected idle, steady, traction "
                             "or braking")
    return out


def choose(probabilities: Sequence[float] | np.ndarray | None, age_s: float | None,
           estimator_ok: bool, table: TargetTable, *, states: Sequence[str] | None = None,
           v_long: Sequence[float] | None = None, class_ids: Sequence[int] | None = None,
           max_age_s: float = MAX_AGE_S) -> PolicyDecision:
    """Pick the served class and (optionally) the per-wheel desired slip (design §10).

    Parameters
    ----------
    probabilities : shape (K,) class probabilities of the latest classification, or None
        (or empty) when none exists yet.
    age_s : s, age of that classification (None when none exists).
    estimator_ok : estimator health (False -> fallback).
    table : desired-slip table (``target(class_id, state)``).
    states, v_long : optional, N wheel states and N longitudinal speeds (m/s); when given,
        ``slip_desired`` holds eq. 8.7-8.9 for the served class.
    class_ids : ids of the K probability entries (default 0..K-1).
    max_age_s : s, staleness limit (default 1.0).

    Returns
    -------
    PolicyDecision
    """
    reason = ""
    p = None if probabilities is None else np.asarray(probabilities, dtype=float).ravel()
    if not estimator_ok:
        reason = "estimator_unhealthy"
    elif p is None or p.size == 0 or age_s is None or not np.all(np.isfinite(p)):
        reason = "no_classification"
    elif not math.isfinite(float(age_s)) or float(age_s) > max_age_s:
        reason = "stale_classification"

    if reason:
        cid, conf = fallback_class_id(table), 0.0
    else:
        assert p is not None
        ids = list(range(p.size)) if class_ids is None else [int(c) for c in class_ids]
        if len(ids) != p.size:
            raise ValueError(f"class_ids ({len(ids)}) and probabilities ({p.size}) differ")
        k = int(np.argmax(p))
        if p[k] >= CONFIDENT_P:
            cid, conf = ids[k], float(p[k])
        else:
            cand = [j for j in range(p.size) if p[j] >= CANDIDATE_P] or [k]
            best = least_aggressive(table, [ids[j] for j in cand])
            cid, conf = best, float(p[ids.index(best)])
    slip: tuple[float, ...] = ()
    if states is not None and v_long is not None:
        slip = tuple(desired_slip_per_wheel(cid, states, v_long, table))
    return PolicyDecision(class_id=int(cid), class_name=_name(table, cid), confidence=conf,
                          slip_desired=slip, fallback=bool(reason), reason=reason)
