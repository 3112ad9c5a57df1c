"""Serving decision of one tick: fused class or the class-free safe cap (design §10-11).

The predictor fuses classifications over distance (:mod:`terrainml.stream.fusion`); this module
turns the fused posterior into what a tick serves:

* **a class**: the argmax of the posterior, with the posterior as confidence, when it is at
  least ``serve_p`` (default 0.6) and the classification is not stale; per wheel
  ``s_des_i = sgn(v_long_i) s_target(class, state_i)`` (eq. 8.7-8.9,
  :func:`terrainml.lookup.policy.desired_slip_per_wheel`);
* **the safe cap** otherwise (design §10, :meth:`DesiredSlipTable.safe_cap` over the model's
  classes, per wheel :func:`terrainml.lookup.policy.safe_cap_per_wheel`): the largest
  traction-peak slip of the classes in traction and steady, the most negative braking target in
  braking, 0 when idle; so no known class is stalled and no wheel runs away. The message names no
  class (``terrain_class`` -1, ``terrain_name`` ``"none"``) and carries the reason.

Reasons, by priority: ``clock_jump`` (the tick's stamp is off the timeline, the chain did not run)
> ``estimator_unhealthy`` > ``classifier_error`` (the last attempt raised, no fused class) >
``no_classification`` (none yet) > ``stale_classification`` (more than ``stale_m`` travelled
since the last classification) > ``uncertain_classification`` (posterior max below ``serve_p``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

from terrainml.lookup.policy import PolicyDecision, desired_slip_per_wheel, safe_cap_per_wheel

__all__ = ["NO_CLASS_ID", "NO_CLASS_NAME", "SERVE_P", "GenericSafeCap", "decide", "safe_cap_for"]

NO_CLASS_ID = -1        # no class served (CAN: 255)
NO_CLASS_NAME = "none"
SERVE_P = 0.6           # design §10: serve the fused argmax at or above this posterior


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


def decide(class_id: int | None, confidence: float, reason: str, table: Any, cap_table: Any,
           cap_classes: Sequence[str] | None, *, states: Sequence[str],
           v_long: Sequence[float], class_name: str = "") -> PolicyDecision:
    """Per-wheel desired slip for a served class, or the safe cap when ``reason`` is set.

    Parameters
    ----------
    class_id, confidence : the fused class and its posterior (ignored when ``reason``).
    reason : "" (serve the class) or a fallback reason.
    table : the desired-slip table (``target(class_id, state)``).
    cap_table, cap_classes : from :func:`safe_cap_for` and the model's class names.
    states, v_long : N wheel states and longitudinal speeds (m/s).
    """
    if reason or class_id is None:
        slip = safe_cap_per_wheel(states, v_long, cap_table, cap_classes)
        return PolicyDecision(class_id=NO_CLASS_ID, class_name=NO_CLASS_NAME, confidence=0.0,
                              slip_desired=tuple(slip), fallback=True,
                              reason=reason or "no_classification")
    slip = desired_slip_per_wheel(int(class_id), states, v_long, table)
    return PolicyDecision(class_id=int(class_id), class_name=class_name, confidence=float(confidence),
                          slip_desired=tuple(slip), fallback=False, reason="")
