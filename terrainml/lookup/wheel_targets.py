"""Per-wheel sign logic of the served targets (design §10, thesis eq. 8.7-8.9).

Per-wheel sign logic (thesis eq. 8.7-8.9)::

    s_des_i = sgn(v_long_i) * s_target(class, state_i)      state_i in traction|braking|steady
    s_des_i = 0                                              state_i == idle (or v_long_i == 0)

``s_target(class, "braking")`` is negative (the braking branch), so forward braking asks for
negative slip and backward braking for positive slip, exactly as thesis Table 8.1.

:func:`desired_slip_per_wheel` applies it to a class's targets, :func:`safe_cap_per_wheel` to
the class-free **safe cap** of design §10 (:meth:`DesiredSlipTable.safe_cap`: the largest
traction target in traction and steady, the most negative braking target in braking). Which of
the two a tick serves, and why, is the serving decision: :mod:`terrainml.stream.tick.policy` holds
every fallback rule and its priority.

These functions are cheap (a few microseconds): they run on every 10 ms tick.
"""

from __future__ import annotations

import math
from typing import Any, Callable, Protocol, Sequence

from terrainml.schema import MOVING_WHEEL_STATES

__all__ = ["TargetTable", "desired_slip_per_wheel", "safe_cap_per_wheel"]


class TargetTable(Protocol):
    """What the policy needs from a table (:class:`terrainml.lookup.table.DesiredSlipTable`)."""

    def target(self, class_id: int, state: str) -> float: ...


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
        elif st in MOVING_WHEEL_STATES:
            out.append(math.copysign(1.0, v) * float(target(st)))
        else:
            raise ValueError(f"unknown wheel state {st!r}; expected idle, steady, traction "
                             "or braking")
    return out
