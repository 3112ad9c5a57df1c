"""The serving decision of one tick: fused class or the class-free safe cap (design §10-11).

Every fallback rule of serving and its priority live here, in :meth:`ServingPolicy.reason`;
the predictor (:mod:`terrainml.stream.tick.predictor`) only gathers the facts of the tick. The
predictor fuses classifications over distance (:mod:`terrainml.stream.tick.fusion`); this module
turns the fused posterior into what a tick serves:

* **a class**: the argmax of the posterior, with the posterior as confidence, when it is at
  least ``serve_p`` (default 0.6) and the classification is not stale; per wheel
  ``s_des_i = sgn(v_long_i) s_target(class, state_i)`` (eq. 8.7-8.9,
  :func:`terrainml.lookup.wheel_targets.desired_slip_per_wheel`);
* **the safe cap** otherwise (design §10, :meth:`DesiredSlipTable.safe_cap` over the model's
  classes, per wheel :func:`terrainml.lookup.wheel_targets.safe_cap_per_wheel`): the largest
  traction-peak slip of the classes in traction and steady, the most negative braking target in
  braking, 0 when idle; so no known class is stalled and no wheel runs away. The message names no
  class (``terrain_class`` -1, ``terrain_name`` ``"none"``) and carries the reason.

Reasons, by priority (:data:`REASON_PRIORITY`): ``clock_jump`` (the tick's stamp is off the
timeline, the chain did not run) > ``estimator_unhealthy`` > ``classifier_error`` (the last
attempt raised, no fused class) > ``unknown_terrain`` (the latest classified windows are unlike
the model's training windows: the fusion filter's ``unknown``, :mod:`terrainml.stream.tick.fusion`;
unknown ground) > ``windows_rejected`` (no class, or a stale one, and every
window rejected while the robot moved more than ``warn_after_m`` healthy: the message's
``fallback_detail`` names the rule and channels) > ``no_classification`` (none yet) > ``stale_classification``
(more than ``stale_m`` travelled since the last classification, or, when ``max_age_s`` is set,
an older one) > ``uncertain_classification`` (posterior max below ``serve_p``). A table or
policy that raises serves zero slip with the tick's reason (``classifier_error`` when none):
serving never stops on it.

Why ``unknown_terrain`` sits there: below the reasons that say the chain itself cannot be
trusted on this tick (a clock jump, an unhealthy estimator, a raising classifier), whose causes
the robot must hear first; above the reasons about the age or confidence of the class
(``windows_rejected``, ``no_classification``, ``stale_classification``, ``uncertain``),
because the ground was judged unlike any trained class, and ageing does not make it known:
windows rejected or a stale class on that stretch keep saying ``unknown_terrain``, so a
controller that refines its cap on unknown ground (``control/cap_refiner.py``) is not switched
off and on by the age rules. It ends only on confirmed known windows (or a new timeline).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any, Protocol, Sequence

import numpy as np

from terrainml.lookup.wheel_targets import desired_slip_per_wheel, safe_cap_per_wheel
from terrainml.lookup.table import CLASS_FREE_DETAIL
from terrainml.stream.tick.message import ESTIMATOR_UNHEALTHY, UNKNOWN_TERRAIN

__all__ = ["REASON_PRIORITY", "NO_CLASS_ID", "NO_CLASS_NAME", "SERVE_P", "GenericSafeCap",
           "PolicyDecision", "ServingPolicy", "safe_cap_for"]

log = logging.getLogger("terrainml.stream")

NO_CLASS_ID = -1        # no class served (CAN: 255)
NO_CLASS_NAME = "none"
SERVE_P = 0.6           # design §10: serve the fused argmax at or above this posterior
#: s of ticks a served state is held before the distance rule turns it stale (no flapping)
HOLD_S = 1.0
#: the reasons of the age and confidence of the class ("" : a class served)
SOFT_REASONS = ("", "stale_classification", "uncertain_classification")
#: the one whose entry is held :data:`HOLD_S` (:meth:`ServingPolicy._held`)
STALE = "stale_classification"
#: the fallback reasons (:data:`terrainml.stream.tick.message.FALLBACK_REASONS`, whose order is
#: their CAN code), highest priority first: the first that applies is served
REASON_PRIORITY = ("clock_jump", ESTIMATOR_UNHEALTHY, "classifier_error", UNKNOWN_TERRAIN,
                   "windows_rejected", "no_classification", "stale_classification",
                   "uncertain_classification")


@dataclass(frozen=True)
class PolicyDecision:
    """What one tick serves.

    Attributes
    ----------
    class_id, class_name : the served class (:data:`NO_CLASS_ID`, :data:`NO_CLASS_NAME` on
        fallback).
    confidence : fused posterior of the served class (0.0 on fallback).
    slip_desired : tuple of N floats, signed per-wheel desired slip.
    fallback : True when the safe cap is served.
    reason : "" or one of :data:`REASON_PRIORITY`.
    detail : for ``windows_rejected``, the rule (and channels) that rejects the windows; for a
        class served without terrain parameters, :data:`~terrainml.lookup.table.CLASS_FREE_DETAIL`;
        else "".
    novelty : the latest window's novelty score over the model's threshold (> 1: unlike the
        training windows), -1.0 without one (no novelty scorer, or no window scored yet).
    """

    class_id: int
    class_name: str
    confidence: float
    slip_desired: tuple[float, ...]
    fallback: bool
    reason: str
    detail: str = ""
    novelty: float = -1.0


class FusedClass(Protocol):
    """What the policy reads of the fusion filter (:class:`~terrainml.stream.tick.fusion.TerrainFilter`)."""

    posterior: np.ndarray | None
    stale: bool
    #: optional (getattr): unknown ground, and the latest window's novelty over its threshold
    #: (:class:`~terrainml.stream.tick.fusion.TerrainFilter`); absent: known, -1.0

    def best(self) -> tuple[int, float]: ...


@dataclass(frozen=True)
class GenericSafeCap:
    """Safe cap of a table without ``safe_cap`` (any ``target(class, state)``): same rule."""

    table: Any
    class_ids: tuple[int, ...]

    def safe_cap(self, classes: Any = None) -> "GenericSafeCap":
        return self

    def target(self, state: str) -> float:
        if state == "idle":
            return 0.0
        if state == "braking":
            return min(float(self.table.target(c, "braking")) for c in self.class_ids)
        return max(float(self.table.target(c, "traction")) for c in self.class_ids)


def safe_cap_for(table: Any, class_ids: Sequence[int], class_names: Sequence[str]) -> Any:
    """What :func:`safe_cap_per_wheel` is called with: the table (``safe_cap`` over the model's
    class names) or, for a table without ``safe_cap``, a :class:`GenericSafeCap`."""
    if callable(getattr(table, "safe_cap", None)) and not isinstance(table, GenericSafeCap):
        table.safe_cap(list(class_names))  # LookupTableError now, not on the first fallback tick
        return table
    return GenericSafeCap(table, tuple(int(c) for c in class_ids))


class ServingPolicy:
    """The fallback rules, their priority and the per-wheel targets of a tick.

    Parameters
    ----------
    table : the desired-slip table (``target(class_id, state)``;
        :class:`terrainml.lookup.table.DesiredSlipTable`).
    class_ids : the K class ids of the fused posterior's entries (the classifier's).
    class_names : names by class id (``class_names[cid]``).
    serve_p : fused posterior below this → ``uncertain_classification``.
    max_age_s : s or None (off): a classification older than this → ``stale_classification``,
        on top of the fusion filter's distance rule.
    """

    def __init__(self, table: Any, class_ids: Sequence[int], class_names: Sequence[str], *,
                 serve_p: float = SERVE_P, max_age_s: float | None = None):
        self.table = table
        self.class_ids = [int(c) for c in class_ids]
        self.class_names = list(class_names)
        self.serve_p = float(serve_p)
        self.max_age_s = None if max_age_s is None else float(max_age_s)
        self._state: Any = None              # the state served (hysteresis, :meth:`_held`)
        self._state_since = -math.inf
        self._state_soft: bool | None = None
        cap_names = [self.name(c) for c in self.class_ids]
        self.cap_classes = cap_names if hasattr(table, "class_names") else None
        self.cap_table = safe_cap_for(table, self.class_ids, cap_names)

    def name(self, cid: int) -> str:
        """Name of a class id (``"none"`` for :data:`NO_CLASS_ID`, the id as text if unnamed)."""
        if cid == NO_CLASS_ID:
            return NO_CLASS_NAME
        return self.class_names[cid] if 0 <= cid < len(self.class_names) else str(cid)

    def safe_cap_traction(self) -> float:
        """Traction target of the safe cap served on fallback (design §10)."""
        return float(self.cap_table.safe_cap(self.cap_classes).target("traction"))

    def reset(self) -> None:
        """A new timeline: no state held."""
        self._state, self._state_since, self._state_soft = None, -math.inf, None

    def _held(self, key: Any, soft: bool, t_s: float) -> Any:
        """The served state with hysteresis (:data:`HOLD_S`): a class id, or a fallback reason.

        A change into ``stale_classification`` from another state of the age and confidence rules
        (:data:`SOFT_REASONS`: a class served, ``uncertain_classification``) waits until that
        state has been served a second of ticks; leaving it for a fresh class, and every other
        change (one class to another, a clock jump, an unhealthy estimator, unknown ground ...),
        apply on their tick. After a sensor pause the distance rule thus turns the class stale at
        most once per second, instead of alternating with it on every classification hop, and a
        fresh classification is never held back (the mixed-terrain course keeps its accuracy).
        ``t_s`` NaN: no hysteresis.
        """
        if not math.isfinite(t_s):
            return key
        # only entering staleness is held: a fresh class is served at once, a stale one waits
        # until the state it replaces has been served a second
        entering_stale = key == STALE and self._state != STALE
        if key != self._state and (not soft or not entering_stale or self._state_soft is False
                                   or not 0 <= t_s - self._state_since < HOLD_S):
            self._state, self._state_since, self._state_soft = key, t_s, soft
        return self._state

    def reason(self, fused: FusedClass, *, estimator_ok: bool, classifier_error: bool,
               age_s: float | None, clock_jump: bool = False, rejected_by: str | None = None,
               t_s: float = math.nan) -> str:
        """The reason this tick cannot serve a class ("" when it can), by priority (design §11).

        ``rejected_by``: the window rule that rejected every window while the robot moved more
        than the set distance healthy (:meth:`ClassificationScheduler.silence`); with no class
        to serve, or a stale one, the tick says so (``windows_rejected``) instead of
        ``no_classification`` / ``stale_classification``.
        """
        if clock_jump:
            return "clock_jump"
        if not estimator_ok:
            return ESTIMATOR_UNHEALTHY
        if classifier_error and fused.posterior is None:
            return "classifier_error"
        if getattr(fused, "unknown", False):
            return UNKNOWN_TERRAIN
        if fused.posterior is None:
            return "windows_rejected" if rejected_by else "no_classification"
        if fused.stale or (self.max_age_s is not None and age_s is not None and age_s > self.max_age_s):
            return "windows_rejected" if rejected_by else "stale_classification"
        if fused.best()[1] < self.serve_p:
            return "uncertain_classification"
        return ""

    def decide(self, fused: FusedClass, *, estimator_ok: bool, classifier_error: bool,
               age_s: float | None, states: Sequence[str], v_long: Sequence[float],
               clock_jump: bool = False, t_s: float = math.nan,
               rejected_by: str | None = None) -> PolicyDecision:
        """What the tick serves: the fused class's targets, or the safe cap with its reason.

        Parameters
        ----------
        fused : the fusion filter (posterior, staleness, argmax).
        estimator_ok, classifier_error, age_s, clock_jump, rejected_by : facts of the tick
            (:meth:`reason`).
        states, v_long : N wheel states and longitudinal speeds (m/s).
        t_s : s, the tick's time (for the log line when the table fails).
        """
        reason = self.reason(fused, estimator_ok=estimator_ok, classifier_error=classifier_error,
                             age_s=age_s, clock_jump=clock_jump, rejected_by=rejected_by, t_s=t_s)
        detail = str(rejected_by) if reason == "windows_rejected" else ""
        nov = float(getattr(fused, "novelty", -1.0))
        try:
            k, post = fused.best()
            soft = reason in SOFT_REASONS and (reason or k >= 0)
            held = self._held(reason or ("class", k), bool(soft), t_s)
            if soft and held != (reason or ("class", k)):
                if isinstance(held, tuple):          # a class held: served with its own posterior
                    k = held[1]
                    post = float(fused.posterior[k]) if fused.posterior is not None else 0.0
                    reason = ""
                else:                                 # a fallback held
                    reason = held
            if reason or k < 0:
                slip = safe_cap_per_wheel(states, v_long, self.cap_table, self.cap_classes)
                return PolicyDecision(class_id=NO_CLASS_ID, class_name=NO_CLASS_NAME,
                                      confidence=0.0, slip_desired=tuple(slip), fallback=True,
                                      reason=reason or "no_classification", detail=detail, novelty=nov)
            cid = self.class_ids[k]
            slip = desired_slip_per_wheel(cid, states, v_long, self.table)
            # a class without terrain parameters is served by name with the class-free safe cap
            # (lookup.table.ClassFreeTargets): said on every such tick, so no one reads it as a class target
            flag = CLASS_FREE_DETAIL if getattr(self.table, "class_free", False) else ""
            return PolicyDecision(class_id=cid, class_name=self.name(cid), confidence=float(post),
                                  slip_desired=tuple(slip), fallback=False, reason="", detail=flag, novelty=nov)
        except Exception as exc:  # noqa: BLE001 - a broken table/policy must not stop serving
            log.warning("policy failed at t=%.3f s (serving zero slip): %s", t_s, exc)
            return PolicyDecision(class_id=NO_CLASS_ID, class_name=NO_CLASS_NAME, confidence=0.0,
                                  slip_desired=(0.0,) * len(states), fallback=True,
                                  reason=reason or "classifier_error", detail=detail, novelty=nov)
