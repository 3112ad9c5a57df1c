"""Desired-slip targets of one terrain class from its force model (design §10, thesis §8.2).

For a class the vehicle's net traction coefficient mu_net(s) (:func:`mu_net_curve`) is evaluated on
the slip grid (:func:`slip_grid`); the traction and braking targets are its peaks or knees and the
steady target its root on s >= 0 (:func:`physics_targets`), the rules of
:mod:`terrainml.lookup.target_rules` applied (a violation by the physics is clamped and recorded in
the row's ``notes``). :mod:`terrainml.lookup.table` holds the rows of all classes.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
from scipy.optimize import brentq

from terrainml.lookup import terramechanics as tm
from terrainml.lookup.target_rules import MAX_MAGNITUDE, MIN_TRACTION_MARGIN, RIGID_PEAK_RANGE
from terrainml.robot import RobotSpec

__all__ = ["LookupTableError", "ClassTargets", "S_MIN", "S_MAX", "N_GRID", "KNEE_FRACTION", "PLATEAU_TOL",
           "slip_grid", "mu_net_curve", "physics_targets", "static_loads"]

S_MIN, S_MAX, N_GRID = -0.8, 0.8, 1601          # 0.001 slip resolution
KNEE_FRACTION = 0.9                             # knee: first slip reaching 90 % of the extreme
PLATEAU_TOL = 0.01                              # peak within 1 % of the end value = no peak


class LookupTableError(ValueError):
    """A table that cannot be built, read or verified."""


@dataclass(frozen=True)
class ClassTargets:
    """One row of the table (slip values are SAE slip, dimensionless)."""

    id: int                          # storage position; the class is known by its name
    name: str
    traction: float
    braking: float
    steady: float
    traction_kind: str = "peak"      # "peak" | "knee" | "given" (direct target of a catalogue)
    braking_kind: str = "peak"
    mu_net_traction_max: float = float("nan")   # mu_net at the traction extreme (NaN if given)
    mu_net_braking_min: float = float("nan")    # mu_net at the braking extreme (NaN if given)
    notes: tuple[str, ...] = ()
    params: dict = field(default_factory=dict)  # the class's TerrainParams, as a dict
    rigid_surface: bool = False      # the 0.10-0.20 traction rule applies
    sources: dict = field(default_factory=dict)  # catalogue: field -> reference or assumption

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["notes"] = list(self.notes)
        for k in ("mu_net_traction_max", "mu_net_braking_min"):  # JSON has no NaN
            d[k] = d[k] if math.isfinite(d[k]) else None
        return d


def slip_grid() -> np.ndarray:
    """The table's slip grid, shape (1601,), -0.8 .. 0.8 in steps of 0.001."""
    return np.linspace(S_MIN, S_MAX, N_GRID)


def mu_net_curve(params: Any, robot: RobotSpec, slip: np.ndarray,
                 loads_n: Sequence[float] | None = None) -> np.ndarray:
    """Vehicle net traction coefficient ``sum (H_i - R_i) / sum W_i`` at equal slip on all wheels.

    Parameters
    ----------
    params : TerrainParams of one class.
    robot : RobotSpec (wheel radius and width; loads from mass and CoM unless given).
    slip : array, shape (M,), SAE slip.
    loads_n : optional per-wheel static loads, N (default ``robot.static_wheel_loads_n()``).

    Returns
    -------
    ndarray, shape (M,), dimensionless.
    """
    loads = list(robot.static_wheel_loads_n() if loads_n is None else loads_n)
    s = np.asarray(slip, dtype=float)
    total = np.zeros_like(s)
    w_sum = 0.0
    # equal loads give equal curves: evaluate each distinct load once
    for w in sorted(set(round(x, 9) for x in loads)):
        k = sum(1 for x in loads if round(x, 9) == w)
        if w <= 0.0:
            continue
        total += k * w * np.asarray(tm.net_traction_coefficient(params, w, s, robot), dtype=float)
        w_sum += k * w
    if w_sum <= 0.0:
        raise LookupTableError(f"robot {robot.name!r}: no wheel carries load "
                               f"(static loads {loads}); check mass and centre of mass")
    return total / w_sum


def _params_dict(params: Any) -> dict:
    if dataclasses.is_dataclass(params):
        d = dataclasses.asdict(params)
    else:  # pragma: no cover - TerrainParams is a dataclass by contract
        d = dict(vars(params))
    return {k: (v if not isinstance(v, float) or math.isfinite(v) else None) for k, v in d.items()}


def _extreme(s: np.ndarray, mu: np.ndarray, sign: float) -> tuple[float, str, float]:
    """Peak or knee on one branch. ``sign`` +1 for traction (max), -1 for braking (min).

    ``s`` is ordered away from zero (|s| increasing). Returns (slip, kind, mu at extreme).
    """
    y = sign * mu
    k = int(np.argmax(y))
    y_max = float(y[k])
    y_end = float(y[-1])
    interior = k < len(y) - 1 and (y_max - y_end) > PLATEAU_TOL * max(abs(y_max), 1e-9)
    if interior:
        return float(s[k]), "peak", float(mu[k])
    # knee: first |s| reaching 90 % of the branch maximum (of the magnitude when it is > 0)
    level = KNEE_FRACTION * y_max if y_max > 0 else y_max
    j = int(np.argmax(y >= level))
    return float(s[j]), "knee", float(mu[k])


def _steady_root(params: Any, robot: RobotSpec, loads: Sequence[float],
                 s_pos: np.ndarray, mu_pos: np.ndarray) -> float | None:
    """Smallest s >= 0 with mu_net(s) = 0 (refined with brentq), None when mu_net < 0 throughout."""
    if mu_pos[0] >= 0.0:
        return 0.0
    above = np.flatnonzero(mu_pos >= 0.0)
    if above.size == 0:
        return None
    j = int(above[0])
    a, b = float(s_pos[j - 1]), float(s_pos[j])
    def f(x: float) -> float:
        return float(mu_net_curve(params, robot, np.array([x]), loads)[0])

    try:
        return float(brentq(f, a, b, xtol=1e-7))
    except ValueError:  # pragma: no cover - grid bracket always changes sign
        return 0.5 * (a + b)


def physics_targets(cid: int, name: str, params: Any, robot: RobotSpec, loads: Sequence[float],
               rigid: bool) -> ClassTargets:
    """Targets of one class from its force model (peak or knee, steady root, rules applied)."""
    s = slip_grid()
    mu = mu_net_curve(params, robot, s, loads)
    if not np.all(np.isfinite(mu)):
        raise LookupTableError(f"class {name}: terramechanics gave non-finite mu_net")
    i0 = int(np.argmin(np.abs(s)))
    s_pos, mu_pos = s[i0:], mu[i0:]
    s_neg, mu_neg = s[: i0 + 1][::-1], mu[: i0 + 1][::-1]   # 0 .. -0.8
    notes: list[str] = []

    s_t, kind_t, mu_t = _extreme(s_pos[1:], mu_pos[1:], +1.0)
    s_b, kind_b, mu_b = _extreme(s_neg[1:], mu_neg[1:], -1.0)
    if mu_t <= 0.0:
        notes.append(f"mu_net never positive (max {mu_t:.3f}): the robot cannot keep speed on "
                     "this class by thrust alone; traction target is the least-negative point")
    root = _steady_root(params, robot, loads, s_pos, mu_pos)
    if root is None:
        s_s = max(0.0, s_t - MIN_TRACTION_MARGIN)
        notes.append(f"no root of mu_net(s) = 0 in [0, {S_MAX}]: steady set to s_T - "
                     f"{MIN_TRACTION_MARGIN}")
    else:
        s_s = root

    # --- rules (design §10); violations by the physics are clamped and recorded
    if rigid:
        lo, hi = RIGID_PEAK_RANGE
        if not lo <= s_t <= hi:
            new = min(max(s_t, lo), hi)
            notes.append(f"rigid-surface traction {kind_t} at s={s_t:.3f} outside "
                         f"[{lo}, {hi}]: clamped to {new:.3f}")
            s_t = new
    for label, val in (("traction", s_t), ("braking", s_b), ("steady", s_s)):
        if abs(val) > MAX_MAGNITUDE:
            new = math.copysign(MAX_MAGNITUDE, val)
            notes.append(f"{label} target {val:.3f} beyond |{MAX_MAGNITUDE}|: clamped")
            if label == "traction":
                s_t = new
            elif label == "braking":
                s_b = new
            else:
                s_s = new
    if s_t < s_s + MIN_TRACTION_MARGIN - 1e-12:
        new_t = s_s + MIN_TRACTION_MARGIN
        if new_t <= MAX_MAGNITUDE and not (rigid and new_t > RIGID_PEAK_RANGE[1]):
            notes.append(f"traction {s_t:.3f} < steady {s_s:.3f} + {MIN_TRACTION_MARGIN}: "
                         f"raised to {new_t:.3f}")
            s_t = new_t
        else:
            new_s = s_t - MIN_TRACTION_MARGIN
            notes.append(f"traction {s_t:.3f} < steady {s_s:.3f} + {MIN_TRACTION_MARGIN} and "
                         f"cannot be raised: steady lowered to {new_s:.3f}")
            s_s = new_s
    return ClassTargets(id=cid, name=name, traction=round(s_t, 6), braking=round(s_b, 6),
                        steady=round(s_s, 6), traction_kind=kind_t, braking_kind=kind_b,
                        mu_net_traction_max=round(mu_t, 6), mu_net_braking_min=round(mu_b, 6),
                        notes=tuple(notes), params=_params_dict(params), rigid_surface=rigid)


def static_loads(robot: RobotSpec) -> list[float]:
    """Static wheel loads (N) from mass and centre of mass, refused when not all positive."""
    loads = robot.static_wheel_loads_n()
    if any(not math.isfinite(w) for w in loads) or sum(loads) <= 0:
        raise LookupTableError(f"robot {robot.name!r}: invalid static wheel loads {loads}")
    if min(loads) <= 0.0:
        raise LookupTableError(
            f"robot {robot.name!r}: a wheel has no static load ({[round(w, 1) for w in loads]}"
            " N): the centre of mass lies outside the wheel support polygon")
    return loads
