"""A slip map: one robust slippage estimator per terrain class or map patch (design §13).

Each entry (``key``: a patch id such as ``"r1c2"`` or a class name) holds, for each target
``beta_left_mps``, ``beta_right_mps``, ``alpha_rad``, the local sufficient statistics
``A = X^T W X``, ``b = X^T W y`` of an IRLS fit (:class:`~terrainml.slipmap.irls.IRLSRegressor`)
on the features of the wheel speeds ``(omega_left, omega_right)``. The estimate is the solve
``A theta = b``; robots exchange their statistics as a small JSON message
(:meth:`SlipMap.to_message`) and :func:`merge_maps` sums them, so the global estimate
``(sum A_k) theta = sum b_k`` equals the centralised weighted fit with every robot's final IRLS
weights.

Predictions clip the inputs to the range of wheel speeds seen in the data of that entry and the
outputs to the range of inlier targets (weight >= 0.5), so a cubic never extrapolates wildly
(both ranges merge exactly as min/max).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Mapping

import numpy as np

from terrainml.atomic import write_text
from terrainml.slipmap.irls import (IRLSRegressor, SufficientStats, polynomial_features,
                                    solve_normal_equations)

TARGETS = ("beta_left_mps", "beta_right_mps", "alpha_rad")
INPUTS = ("omega_left_radps", "omega_right_radps")
MESSAGE_SCHEMA = "terrainml.slipmap"
MESSAGE_VERSION = 1
INLIER_WEIGHT = 0.5


class SlipMapError(ValueError):
    """A slip map message or merge is invalid (the message says which field)."""


@dataclass
class SlipMapConfig:
    """Settings that every robot of a fleet must share for their maps to merge.

    Attributes
    ----------
    degree : polynomial degree of the wheel-speed features (paper: 3).
    norm : robust norm, "huber" or "bisquare".
    tuning : norm tuning constant (None: statsmodels' defaults 1.345 / 4.685).
    input_scale_radps : wheel speeds are divided by this before the expansion (rad/s).
    ridge : relative Tikhonov term of the solve, ``(A + ridge * tr(A) / p * I) theta = b``
        (0: plain weighted least squares). A small value keeps directions the data do not excite
        (a robot driving at one speed only) at zero instead of arbitrary; it is added after the
        merge, so the merged solve still equals the centralised one with the same ridge.
    wheel_radius_m, track_width_m : robot geometry used to compute the targets (metadata).
    """

    degree: int = 3
    norm: str = "huber"
    tuning: float | None = None
    input_scale_radps: float = 10.0
    wheel_radius_m: float = 0.1
    track_width_m: float = 0.5
    ridge: float = 0.0

    def merge_key(self) -> tuple:
        return (self.degree, self.norm, self.tuning, self.input_scale_radps, self.ridge)

    def regressor(self) -> IRLSRegressor:
        return IRLSRegressor(degree=self.degree, norm=self.norm, tuning=self.tuning,
                             input_scale=self.input_scale_radps)


@dataclass
class PatchEstimate:
    """Statistics of one map entry (all three targets)."""

    stats: dict[str, SufficientStats]
    x_min: np.ndarray  # (2,) rad/s
    x_max: np.ndarray
    y_min: np.ndarray  # (3,) target units, inliers only
    y_max: np.ndarray
    _coef: np.ndarray | None = field(default=None, repr=False)
    _ridge: float = field(default=0.0, repr=False)

    @property
    def n(self) -> int:
        return next(iter(self.stats.values())).n

    def coef(self, ridge: float = 0.0) -> np.ndarray:
        """Coefficients, shape (3, n_features): one row per target."""
        if self._coef is None or self._ridge != ridge:
            rows = []
            for t in TARGETS:
                s = self.stats[t]
                a = s.a
                if ridge > 0:
                    p = a.shape[0]
                    a = a + ridge * np.trace(a) / p * np.eye(p)
                rows.append(solve_normal_equations(a, s.b))
            self._coef = np.vstack(rows)
            self._ridge = ridge
        return self._coef

    def __add__(self, other: "PatchEstimate") -> "PatchEstimate":
        return PatchEstimate(stats={t: self.stats[t] + other.stats[t] for t in TARGETS},
                             x_min=np.minimum(self.x_min, other.x_min),
                             x_max=np.maximum(self.x_max, other.x_max),
                             y_min=np.minimum(self.y_min, other.y_min),
                             y_max=np.maximum(self.y_max, other.y_max))


class SlipMap:
    """Container of per-patch (or per-class) slippage estimators.

    Parameters
    ----------
    config : SlipMapConfig
    robot_id : str, name of the robot (or "merged") that produced the statistics.
    """

    def __init__(self, config: SlipMapConfig | None = None, robot_id: str = "robot"):
        self.config = config or SlipMapConfig()
        self.robot_id = robot_id
        self.patches: dict[str, PatchEstimate] = {}

    # ------------------------------------------------------------------ fit
    def fit_patch(self, key: str, omega_lr_radps, targets) -> "SlipMap":
        """Fit (replace) the estimators of one entry by IRLS.

        Parameters
        ----------
        key : entry name (patch id or terrain class name).
        omega_lr_radps : array, shape (n, 2)  left and right wheel speeds (rad/s).
        targets : array, shape (n, 3)  beta_left (m/s), beta_right (m/s), alpha (rad).
        """
        x = np.asarray(omega_lr_radps, dtype=float)
        y = np.asarray(targets, dtype=float)
        if x.ndim != 2 or x.shape[1] != 2:
            raise ValueError(f"omega_lr_radps must have shape (n, 2), got {x.shape}")
        if y.shape != (x.shape[0], len(TARGETS)):
            raise ValueError(f"targets must have shape ({x.shape[0]}, 3), got {y.shape}")
        stats, y_min, y_max = {}, [], []
        for j, name in enumerate(TARGETS):
            reg = self.config.regressor().fit(x, y[:, j])
            stats[name] = reg.sufficient_stats()
            inl = reg.weights_ >= INLIER_WEIGHT
            yy = y[inl, j] if inl.any() else y[:, j]
            y_min.append(yy.min())
            y_max.append(yy.max())
        self.patches[str(key)] = PatchEstimate(stats=stats, x_min=x.min(axis=0), x_max=x.max(axis=0),
                                               y_min=np.array(y_min), y_max=np.array(y_max))
        return self

    # ------------------------------------------------------------------ predict
    def coef(self, key: str) -> np.ndarray:
        """Coefficients of one entry, shape (3, n_features)."""
        return self.patches[str(key)].coef(self.config.ridge)

    def predict(self, keys, omega_lr_radps, fill: float = np.nan) -> np.ndarray:
        """Predicted (beta_left, beta_right, alpha) per sample.

        Parameters
        ----------
        keys : sequence of str, length n  entry per sample (unknown entries give ``fill``).
        omega_lr_radps : array, shape (n, 2)

        Returns
        -------
        array, shape (n, 3): beta_left (m/s), beta_right (m/s), alpha (rad).
        """
        x = np.atleast_2d(np.asarray(omega_lr_radps, dtype=float))
        keys = np.asarray(keys, dtype=object).reshape(-1)
        out = np.full((x.shape[0], len(TARGETS)), fill, dtype=float)
        for key in np.unique(keys.astype(str)):
            pe = self.patches.get(key)
            if pe is None:
                continue
            rows = keys.astype(str) == key
            xc = np.clip(x[rows], pe.x_min, pe.x_max)
            feats = polynomial_features(xc, self.config.degree, self.config.input_scale_radps)
            out[rows] = np.clip(feats @ pe.coef(self.config.ridge).T, pe.y_min, pe.y_max)
        return out

    # ------------------------------------------------------------------ message
    def to_message(self) -> dict:
        """A JSON-serialisable message with every entry's statistics (A stored as its upper triangle)."""
        p = None
        patches = {}
        for key, pe in sorted(self.patches.items()):
            st = {}
            for t in TARGETS:
                s = pe.stats[t]
                p = s.a.shape[0]
                iu = np.triu_indices(p)
                st[t] = {"a_upper": s.a[iu].tolist(), "b": s.b.tolist(), "n": s.n, "sum_w": s.sum_w}
            patches[key] = {"x_min": pe.x_min.tolist(), "x_max": pe.x_max.tolist(),
                            "y_min": pe.y_min.tolist(), "y_max": pe.y_max.tolist(), "stats": st}
        c = self.config
        return {"schema": MESSAGE_SCHEMA, "schema_version": MESSAGE_VERSION, "robot_id": self.robot_id,
                "config": {"degree": c.degree, "norm": c.norm, "tuning": c.tuning,
                           "input_scale_radps": c.input_scale_radps, "wheel_radius_m": c.wheel_radius_m,
                           "track_width_m": c.track_width_m, "ridge": c.ridge},
                "inputs": list(INPUTS), "targets": list(TARGETS), "patches": patches}

    def to_json(self) -> str:
        return json.dumps(self.to_message(), sort_keys=True)

    @classmethod
    def from_message(cls, msg: Mapping, source: str = "<message>") -> "SlipMap":
        """Rebuild a map from :meth:`to_message` output; raises :class:`SlipMapError` naming the field."""
        if not isinstance(msg, Mapping) or msg.get("schema") != MESSAGE_SCHEMA:
            raise SlipMapError(f"{source}: not a slip map message (field 'schema' must be '{MESSAGE_SCHEMA}')")
        if msg.get("schema_version") != MESSAGE_VERSION:
            raise SlipMapError(f"{source}: unsupported field 'schema_version' {msg.get('schema_version')!r} "
                               f"(this terrainml reads {MESSAGE_VERSION})")
        if list(msg.get("targets", [])) != list(TARGETS):
            raise SlipMapError(f"{source}: field 'targets' must be {list(TARGETS)}")
        try:
            cfg = SlipMapConfig(**msg["config"])
            smap = cls(cfg, robot_id=str(msg.get("robot_id", "robot")))
            p = polynomial_features(np.zeros((1, 2)), cfg.degree, cfg.input_scale_radps).shape[1]
            iu = np.triu_indices(p)
            for key, d in msg["patches"].items():
                stats = {}
                for t in TARGETS:
                    s = d["stats"][t]
                    a = np.zeros((p, p))
                    a[iu] = np.asarray(s["a_upper"], dtype=float)
                    a = a + np.triu(a, 1).T
                    b = np.asarray(s["b"], dtype=float)
                    if b.shape != (p,):
                        raise SlipMapError(f"{source}: patch '{key}' target '{t}': field 'b' must have {p} values")
                    stats[t] = SufficientStats(a=a, b=b, n=int(s["n"]), sum_w=float(s["sum_w"]))
                smap.patches[str(key)] = PatchEstimate(
                    stats=stats, x_min=np.asarray(d["x_min"], float), x_max=np.asarray(d["x_max"], float),
                    y_min=np.asarray(d["y_min"], float), y_max=np.asarray(d["y_max"], float))
        except SlipMapError:
            raise
        except (KeyError, TypeError, ValueError) as exc:
            raise SlipMapError(f"{source}: malformed slip map message ({type(exc).__name__}: {exc})") from None
        return smap

    @classmethod
    def from_json(cls, text: str, source: str = "<json>") -> "SlipMap":
        try:
            msg = json.loads(text)
        except json.JSONDecodeError as exc:
            raise SlipMapError(f"{source}: not valid JSON ({exc})") from None
        return cls.from_message(msg, source)

    def save(self, path: str | Path) -> Path:
        return write_text(path, self.to_json())   # whole or not at all

    @classmethod
    def load(cls, path: str | Path) -> "SlipMap":
        path = Path(path)
        if not path.is_file():
            raise SlipMapError(f"{path}: file not found")
        return cls.from_json(path.read_text(), str(path))


def merge_maps(maps: Iterable[SlipMap], robot_id: str = "merged") -> SlipMap:
    """Exact merge of several robots' maps: per entry and target, sum the statistics.

    The result's coefficients solve ``(sum_k A_k) theta = sum_k b_k`` (design §13). Entries present
    in only some maps are taken from those.
    """
    maps = list(maps)
    if not maps:
        raise SlipMapError("merge needs at least one slip map")
    key0 = maps[0].config.merge_key()
    for m in maps[1:]:
        if m.config.merge_key() != key0:
            raise SlipMapError(f"cannot merge maps with different settings: {maps[0].robot_id} has "
                               f"{key0}, {m.robot_id} has {m.config.merge_key()} "
                               "(degree, norm, tuning, input_scale_radps, ridge)")
    out = SlipMap(maps[0].config, robot_id=robot_id)
    for m in maps:
        for key, pe in m.patches.items():
            out.patches[key] = pe if key not in out.patches else out.patches[key] + pe
    return out
