"""Desired-slip table: class x {traction, braking, steady} from terramechanics and the robot spec
(design §10, thesis §8.2).

Classes are known by name: a table is built for the eight simulated classes
(:meth:`DesiredSlipTable.build`) or for any class set from a terrain catalogue
(:meth:`DesiredSlipTable.from_catalogue`, :mod:`terrainml.lookup.catalogue`), whose classes give
either terramechanics parameters (targets computed as below) or direct targets (served as given).
Integer ids are storage details (the position of a class in the table); lookups take the name
or the id, and :meth:`DesiredSlipTable.check_classes` refuses a table that does not hold a
model's classes under the model's ids (what serving checks on load).
:meth:`DesiredSlipTable.safe_cap` is the class-free fallback target of design §10.
:class:`ClassFreeTargets` serves that cap, taken over the reference catalogue's classes, to every
class of a model whose class names no catalogue knows (a team's own names), until one is given.

For every terrain class the table evaluates the vehicle's net traction coefficient

    mu_net(s) = sum_i (H_i(s) - R_i(s)) / sum_i W_i          s in [-0.8, 0.8]

with H and R from :mod:`terrainml.lookup.terramechanics` (the one source of truth the simulator
uses too), evaluated at every wheel's static load ``W_i`` (``robot.static_wheel_loads_n()``:
mass and centre of mass), the robot's wheel radius and width, and the same slip on every wheel.
With equal loads this is the single-wheel curve mu_net = DP / W of design §6.2; with unequal
loads it is the load-weighted vehicle curve (the drawbar-pull coefficient of the whole robot).

Targets (design §10):

* traction ``s_T``: slip of the traction peak point (argmax of mu_net on s > 0) when the peak is
  interior; otherwise (the curve still rises, or is flat within ``PLATEAU_TOL`` of its maximum,
  at s = 0.8) the *knee*, the smallest s with mu_net >= 0.9 max;
* braking ``s_B < 0``: the same on the braking branch (argmin of mu_net on s < 0, or the
  smallest |s| with mu_net <= 0.9 min);
* steady ``s_S``: the root of mu_net(s) = 0 on s >= 0 (thrust balances motion resistance at
  cruise: the minimal slip that keeps speed).

Rules that keep the table physical, enforced at build time (a violation by the physics is
clamped and recorded in the class's ``notes``) and verified again by :meth:`from_json`:

* ``s_T >= s_S + 0.03``;
* rigid-surface classes (``pavement``, ``compacted_dirt``, or ``rigid_surface: true`` in a
  catalogue) have their traction target in [0.10, 0.20];
* no target beyond 0.6 in magnitude.

The JSON form carries the table, the class parameters it came from, the slip grid, the wheel
loads, the robot spec and its sha256, and a checksum of the whole content.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Sequence

from terrainml import __version__
from terrainml.atomic import write_text
from terrainml.classes import TERRAIN_CLASSES
from terrainml.lookup import terramechanics as tm
from terrainml.lookup.catalogue import CatalogueClass, TerrainCatalogue, load_catalogue
from terrainml.lookup.slip_targets import (KNEE_FRACTION, N_GRID, PLATEAU_TOL, S_MAX, S_MIN,
                                           ClassTargets as ClassTargets, LookupTableError as LookupTableError,
                                           mu_net_curve as mu_net_curve, physics_targets, slip_grid as slip_grid,
                                           static_loads)
from terrainml.lookup.target_rules import (MAX_MAGNITUDE, MIN_TRACTION_MARGIN, RIGID_CLASSES as RIGID_CLASSES,
                                           RIGID_PEAK_RANGE)
from terrainml.robot import RobotSpec, reference_robot
from terrainml.schema import WHEEL_STATES

__all__ = ["ClassFreeTargets", "ClassTargets", "DesiredSlipTable", "LookupTableError", "RIGID_CLASSES",
           "SafeCap", "mu_net_curve", "STATES", "CLASS_FREE_DETAIL"]

SCHEMA = "terrainml.desired_slip_table"
SCHEMA_VERSION = 1
STATES = WHEEL_STATES


@dataclass(frozen=True)
class SafeCap:
    """Class-free fallback target (design §10): stalls no class of the table, lets no wheel run away.

    Attributes
    ----------
    traction : largest traction target s_T over the classes (SAE slip, > 0); also served in
        ``steady`` (a cap at any class's steady slip would stall the classes that cruise at more).
    braking : most negative braking target s_B over the classes (< 0).
    traction_class, braking_class : names of the classes they come from.
    """

    traction: float
    braking: float
    traction_class: str
    braking_class: str

    def target(self, state: str) -> float:
        """Target in a wheel state (``idle`` -> 0, ``steady``/``traction`` -> s_T, braking -> s_B)."""
        if state == "idle":
            return 0.0
        if state in ("steady", "traction"):
            return self.traction
        if state == "braking":
            return self.braking
        raise ValueError(f"unknown wheel state {state!r}; expected one of {', '.join(STATES)}")



def _given_row(cid: int, cls: CatalogueClass) -> ClassTargets:
    """A catalogue class with direct targets: served as given (validated by the catalogue)."""
    t = cls.targets or {}
    return ClassTargets(id=cid, name=cls.name, traction=float(t["traction"]),
                        braking=float(t["braking"]), steady=float(t["steady"]),
                        traction_kind="given", braking_kind="given",
                        rigid_surface=cls.rigid_surface, sources=dict(cls.sources))



def _meta(rigid_classes: Sequence[str]) -> dict:
    return {"terrainml_version": __version__,
            "slip_grid": {"min": S_MIN, "max": S_MAX, "n": N_GRID},
            "rules": {"min_traction_margin": MIN_TRACTION_MARGIN,
                      "rigid_peak_range": list(RIGID_PEAK_RANGE),
                      "rigid_classes": list(rigid_classes),
                      "max_magnitude": MAX_MAGNITUDE, "knee_fraction": KNEE_FRACTION,
                      "plateau_tol": PLATEAU_TOL}}


def _float_or_nan(value: Any) -> float:
    return float("nan") if value is None else float(value)


def _checksum(doc: dict) -> str:
    body = {k: v for k, v in doc.items() if k != "checksum_sha256"}
    return hashlib.sha256(json.dumps(body, sort_keys=True, allow_nan=False).encode()).hexdigest()


class DesiredSlipTable:
    """Class x {traction, braking, steady} desired-slip targets for one robot (design §10).

    Build with :meth:`build` (the eight simulated classes) or :meth:`from_catalogue` (any class
    set, by name); read with :meth:`from_json`. ``target(name_or_id, state)`` is a dict lookup
    (cheap enough for every 10 ms tick).

    Attributes
    ----------
    rows : tuple of ClassTargets, ordered by class id (the storage position).
    robot_sha256 : sha256 of the robot spec the table was built for.
    robot_spec : dict, that spec.
    wheel_loads_n : tuple of static wheel loads used, N.
    """

    def __init__(self, rows: Iterable[ClassTargets], *, robot_spec: dict, robot_sha256: str,
                 wheel_loads_n: Sequence[float], meta: dict | None = None) -> None:
        self.rows = tuple(sorted(rows, key=lambda r: r.id))
        if not self.rows:
            raise LookupTableError("a desired-slip table needs at least one class")
        self.robot_spec = dict(robot_spec)
        self.robot_sha256 = str(robot_sha256)
        self.wheel_loads_n = tuple(float(w) for w in wheel_loads_n)
        self.meta = dict(meta or {})
        self._by_id = {r.id: r for r in self.rows}
        self._by_name = {r.name: r for r in self.rows}
        if len(self._by_id) != len(self.rows) or len(self._by_name) != len(self.rows):
            raise LookupTableError("a desired-slip table names each class once, with one id "
                                   f"(classes {[(r.id, r.name) for r in self.rows]})")
        # keyed by id and by name: either is one dict lookup
        self._targets: dict[tuple[int | str, str], float] = {}
        for r in self.rows:
            for key in (r.id, r.name):
                self._targets[(key, "idle")] = 0.0
                self._targets[(key, "steady")] = float(r.steady)
                self._targets[(key, "traction")] = float(r.traction)
                self._targets[(key, "braking")] = float(r.braking)

    # ------------------------------------------------------------------ build
    @classmethod
    def build(cls, robot: RobotSpec | None = None,
              class_ids: Sequence[int] | None = None, params: dict | None = None
              ) -> "DesiredSlipTable":
        """Compute the table for a robot from the nominal class parameters.

        Parameters
        ----------
        robot : RobotSpec (default the reference robot).
        class_ids : classes to include (default all eight of design §6.1).
        params : optional {class_id: TerrainParams} overriding the nominal parameters.
        """
        robot = robot if robot is not None else reference_robot()
        loads = static_loads(robot)
        ids = list(range(len(TERRAIN_CLASSES))) if class_ids is None else [int(c) for c in class_ids]
        rows = []
        for cid in ids:
            p = (params or {}).get(cid) or tm.nominal_params(cid)
            name = TERRAIN_CLASSES[cid]
            rows.append(physics_targets(cid, name, p, robot, loads, rigid=name in RIGID_CLASSES))
        return cls(rows, robot_spec=robot.to_dict(), robot_sha256=robot.sha256(),
                   wheel_loads_n=loads, meta=_meta(RIGID_CLASSES))

    @classmethod
    def from_catalogue(cls, catalogue: TerrainCatalogue | str | Path,
                       robot: RobotSpec | None = None,
                       class_names: Sequence[str] | None = None) -> "DesiredSlipTable":
        """Compute the table for a robot and a class set from a terrain catalogue.

        Parameters
        ----------
        catalogue : TerrainCatalogue, built-in name (``reference``, ``borealtc``) or YAML path.
        robot : RobotSpec (default the reference robot): static
            wheel loads from mass and centre of mass, wheel radius and width.
        class_names : the class set, in the order that gives the ids (e.g. a model's class
            names); default every catalogue class in file order. A name the catalogue lacks is
            refused (:class:`terrainml.lookup.catalogue.CatalogueError`, naming the file).

        Returns
        -------
        DesiredSlipTable whose row ``k`` is ``class_names[k]``. Terramechanics classes are
        computed as in :meth:`build`; direct-target classes are served as given.
        """
        cat = load_catalogue(catalogue)
        chosen = cat.select(class_names)
        robot = robot if robot is not None else reference_robot()
        loads = static_loads(robot)
        rows = []
        for cid, c in enumerate(chosen):
            if c.params is None:
                rows.append(_given_row(cid, c))
                continue
            row = physics_targets(cid, c.name, dataclasses.replace(c.params, class_id=cid), robot,
                             loads, rigid=c.rigid_surface)
            rows.append(dataclasses.replace(row, sources=dict(c.sources)))
        meta = _meta([c.name for c in chosen if c.rigid_surface])
        meta["catalogue"] = {"name": cat.name, "source": cat.source, "sha256": cat.sha256}
        return cls(rows, robot_spec=robot.to_dict(), robot_sha256=robot.sha256(),
                   wheel_loads_n=loads, meta=meta)

    # ------------------------------------------------------------------ lookup
    @property
    def class_ids(self) -> tuple[int, ...]:
        return tuple(r.id for r in self.rows)

    @property
    def class_names(self) -> tuple[str, ...]:
        """The table's class names, in id order."""
        return tuple(r.name for r in self.rows)

    def class_name(self, class_id: int) -> str:
        return self.row(class_id).name

    def row(self, cls: int | str) -> ClassTargets:
        """The row of a class, by name (or by its storage id)."""
        if isinstance(cls, str):
            try:
                return self._by_name[cls]
            except KeyError:
                raise LookupTableError(f"class {cls!r} is not in the desired-slip table (its "
                                       f"classes: {', '.join(self.class_names)})") from None
        try:
            return self._by_id[int(cls)]
        except (KeyError, TypeError, ValueError):
            raise LookupTableError(f"class id {cls} not in the desired-slip table "
                                   f"(classes {list(self._by_id)})") from None

    def target(self, cls: int | str, state: str) -> float:
        """Unsigned-direction target of a class (name or id) in a state (idle -> 0; braking < 0)."""
        try:
            return self._targets[(cls, state)]
        except (KeyError, TypeError):
            if state not in STATES:
                raise ValueError(f"unknown wheel state {state!r}; expected one of "
                                 f"{', '.join(STATES)}") from None
            return self._targets[(self.row(cls).id, state)]

    def check_classes(self, class_ids: Sequence[int], class_names: Sequence[str],
                      source: str = "the model") -> None:
        """Refuse a table that does not hold the model's classes under the model's ids.

        The serving policy looks targets up by class id, so the table's class ``cid`` must be
        the model's class ``cid``, matched by name; a table with more classes is fine (the
        reference table serves a model trained on some of its classes). Serving runs this check
        when it opens a model (:func:`terrainml.stream.tick.classify.load_serving_model`).

        Parameters
        ----------
        class_ids, class_names : the model's class ids and their names (same length).
        source : what the message names (the table file or the model folder).

        Raises
        ------
        LookupTableError naming ``source``, listing both class sets and the ids that differ.
        """
        rows = list(self.class_names)
        bad = [(int(c), str(n)) for c, n in zip(class_ids, class_names)
               if not (0 <= int(c) < len(rows) and rows[int(c)] == str(n))]
        if bad:
            raise LookupTableError(
                f"{source}: the desired-slip table's classes {rows} are not the model's "
                f"{[str(n) for n in class_names]} (by id: {bad} differ); serve a table built for "
                "the model's classes (`terrainml lookup build --catalogue ...`)")

    def safe_cap(self, classes: Iterable[str] | None = None) -> SafeCap:
        """The class-free fallback target (design §10) over the table's classes.

        The largest traction target s_T (served in traction and steady) and the most negative
        braking target s_B: every class's own target lies within the cap, so no class is
        stalled by it, and the slip stays bounded (no wheel runs away).

        Parameters
        ----------
        classes : optional subset of class names (default all the table's classes).
        """
        rows = self.rows if classes is None else [self.row(str(c)) for c in classes]
        if not rows:
            raise LookupTableError("safe_cap needs at least one class")
        t = max(rows, key=lambda r: r.traction)
        b = min(rows, key=lambda r: r.braking)
        return SafeCap(traction=float(t.traction), braking=float(b.braking),
                       traction_class=t.name, braking_class=b.name)

    def check_rules(self) -> list[str]:
        """Violations of the design §10 rules (empty when the table is physical)."""
        bad = []
        for r in self.rows:
            if not r.traction >= r.steady + MIN_TRACTION_MARGIN - 1e-9:
                bad.append(f"{r.name}: traction {r.traction} < steady {r.steady} + "
                           f"{MIN_TRACTION_MARGIN}")
            if r.rigid_surface and not (RIGID_PEAK_RANGE[0] - 1e-9 <= r.traction
                                                <= RIGID_PEAK_RANGE[1] + 1e-9):
                bad.append(f"{r.name}: rigid-surface traction {r.traction} outside "
                           f"{list(RIGID_PEAK_RANGE)}")
            for label in ("traction", "braking", "steady"):
                v = getattr(r, label)
                if not (math.isfinite(v) and abs(v) <= MAX_MAGNITUDE + 1e-9):
                    bad.append(f"{r.name}: {label} {v} beyond |{MAX_MAGNITUDE}|")
            if not r.braking < 0.0 or not r.traction > 0.0 or not r.steady >= 0.0:
                bad.append(f"{r.name}: signs must be traction > 0, braking < 0, steady >= 0")
        return bad

    # ------------------------------------------------------------------ io
    def to_summary(self) -> dict:
        """``{"classes": [{"id", "name", "traction", "braking", "steady"}, ...]}``."""
        return {"classes": [{"id": r.id, "name": r.name, "traction": round(r.traction, 4),
                             "braking": round(r.braking, 4), "steady": round(r.steady, 4)}
                            for r in self.rows]}

    def to_dict(self) -> dict:
        doc = {"schema": SCHEMA, "schema_version": SCHEMA_VERSION,
               "robot": {"name": self.robot_spec.get("name"), "sha256": self.robot_sha256,
                         "spec": self.robot_spec},
               "wheel_loads_n": list(self.wheel_loads_n),
               "meta": self.meta,
               "classes": [r.to_dict() for r in self.rows]}
        doc["checksum_sha256"] = _checksum(doc)
        return doc

    def to_json(self, indent: int | None = 2) -> str:
        return json.dumps(self.to_dict(), indent=indent, allow_nan=False)

    @classmethod
    def from_json(cls, text: str | bytes, *, robot: RobotSpec | None = None,
                  source: str = "<json>") -> "DesiredSlipTable":
        """Read and verify a table: schema, checksum, robot spec hash, rules.

        Parameters
        ----------
        text : the JSON written by :meth:`to_json` (str, or UTF-8 bytes).
        robot : optional robot the table must have been built for (sha256 compared).
        source : name used in error messages (a file path).

        Raises
        ------
        LookupTableError naming ``source`` for anything that is not such a table: binary data,
        invalid or deeply nested JSON, JSON of another shape, a wrong checksum or robot.
        """
        try:
            doc = json.loads(text)
        except UnicodeDecodeError:
            raise LookupTableError(f"{source}: not a desired-slip table (binary data, not "
                                   "UTF-8 JSON)") from None
        except (ValueError, RecursionError) as exc:  # JSONDecodeError is a ValueError
            raise LookupTableError(f"{source}: not valid JSON ({exc})") from None
        if not isinstance(doc, dict) or doc.get("schema") != SCHEMA:
            got = (f"schema {doc.get('schema')!r}" if isinstance(doc, dict)
                   else f"a JSON {type(doc).__name__}")
            raise LookupTableError(f"{source}: not a terrainml desired-slip table (expected an "
                                   f"object with schema {SCHEMA!r}, got {got})")
        if doc.get("schema_version") != SCHEMA_VERSION:
            raise LookupTableError(f"{source}: schema version {doc.get('schema_version')!r}, "
                                   f"this terrainml reads {SCHEMA_VERSION}")
        try:
            checksum = _checksum(doc)
        except ValueError as exc:  # NaN/Infinity literals: never written by to_json
            raise LookupTableError(f"{source}: malformed desired-slip table ({exc})") from None
        if doc.get("checksum_sha256") != checksum:
            raise LookupTableError(f"{source}: checksum mismatch: the table was modified after "
                                   "it was written")
        try:
            spec = doc["robot"]["spec"]
            sha = doc["robot"]["sha256"]
            spec_sha = RobotSpec.from_dict(spec, source=f"{source}:robot").sha256()
            rows = [ClassTargets(id=int(c["id"]), name=str(c["name"]),
                                 traction=float(c["traction"]), braking=float(c["braking"]),
                                 steady=float(c["steady"]),
                                 traction_kind=str(c.get("traction_kind", "peak")),
                                 braking_kind=str(c.get("braking_kind", "peak")),
                                 mu_net_traction_max=_float_or_nan(c.get("mu_net_traction_max")),
                                 mu_net_braking_min=_float_or_nan(c.get("mu_net_braking_min")),
                                 notes=tuple(c.get("notes", ())), params=dict(c.get("params", {})),
                                 # tables written before catalogues: the rule applied by name
                                 rigid_surface=bool(c.get("rigid_surface",
                                                          str(c["name"]) in RIGID_CLASSES)),
                                 sources=dict(c.get("sources", {})))
                    for c in doc["classes"]]
            table = cls(rows, robot_spec=spec, robot_sha256=sha,
                        wheel_loads_n=doc.get("wheel_loads_n", []), meta=doc.get("meta", {}))
        except LookupTableError as exc:
            raise LookupTableError(f"{source}: malformed desired-slip table ({exc})") from None
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise LookupTableError(f"{source}: malformed desired-slip table ({exc})") from None
        if spec_sha != sha:
            raise LookupTableError(f"{source}: robot spec sha256 {spec_sha[:12]} does not match "
                                   f"the recorded {str(sha)[:12]}")
        if robot is not None:
            want = robot
            if want.sha256() != sha:
                raise LookupTableError(
                    f"{source}: table was built for robot {spec.get('name')!r} "
                    f"(sha256 {str(sha)[:12]}), not for {want.name!r} "
                    f"(sha256 {want.sha256()[:12]}); rebuild it with `terrainml lookup build`")
        bad = table.check_rules()
        if bad:
            raise LookupTableError(f"{source}: table breaks the design §10 rules: "
                                   + "; ".join(bad))
        return table

    def save(self, path) -> None:
        write_text(path, self.to_json() + "\n")

    @classmethod
    def load(cls, path, *, robot: RobotSpec | None = None) -> "DesiredSlipTable":
        """Read and verify a table file (see :meth:`from_json`); every refusal names the file."""
        p = Path(path)
        if not p.is_file():
            raise LookupTableError(f"{p}: desired-slip table file not found")
        try:
            data = p.read_bytes()  # bytes: binary junk is refused by from_json, not by a decoder
        except OSError as exc:
            raise LookupTableError(f"{p}: cannot read the desired-slip table "
                                   f"({exc.strerror or exc})") from None
        return cls.from_json(data, robot=robot, source=str(p))

    def __repr__(self) -> str:
        body = ", ".join(f"{r.name}: T{r.traction:+.3f} B{r.braking:+.3f} S{r.steady:+.3f}"
                         for r in self.rows)
        return f"DesiredSlipTable({self.robot_spec.get('name')!r}; {body})"


#: what a served message says (``fallback_detail``) when its class has no terrain parameters
CLASS_FREE_DETAIL = "class_free_targets: no terrain parameters for this class (train --catalogue)"


class ClassFreeTargets:
    """Targets of a model whose classes no terrain catalogue describes (design §10).

    A team's own class names (``gravel_lot``, ``B2``) have no terramechanics parameters, so no
    class target can be computed. Every class is then served the class-free safe cap of the
    reference catalogue's eight classes for the robot (:meth:`DesiredSlipTable.safe_cap` of
    :meth:`DesiredSlipTable.build`; 0.567 / -0.580 for the Husky): a target that stalls none of
    the terrains we have parameters for and lets no wheel run away. The class itself is still
    classified and served by name; the stream flags such ticks (:data:`CLASS_FREE_DETAIL`).
    A catalogue with the classes (``train --catalogue``) replaces it with class targets.

    Parameters
    ----------
    cap : the safe cap served to every class.
    class_names : the model's class names by id (``class_names[cid]``).
    """

    class_free = True

    def __init__(self, cap: SafeCap, class_names: Sequence[str]):
        self.cap = cap
        self._names = tuple(str(n) for n in class_names)

    @classmethod
    def for_robot(cls, robot: RobotSpec, class_names: Sequence[str]) -> "ClassFreeTargets":
        """The reference catalogue's safe cap for ``robot``, served to ``class_names``."""
        return cls(DesiredSlipTable.build(robot).safe_cap(), class_names)

    @property
    def class_names(self) -> tuple[str, ...]:
        return self._names

    def target(self, cls: int | str, state: str) -> float:
        """The safe cap's target in ``state`` whatever the class (``idle`` -> 0)."""
        if state not in STATES:
            raise LookupTableError(f"unknown state {state!r}; expected one of {STATES}")
        return self.cap.target(state)

    def safe_cap(self, classes: Iterable[str] | None = None) -> SafeCap:
        """The same cap (class-free by construction)."""
        return self.cap

    def check_classes(self, class_ids: Sequence[int], class_names: Sequence[str], source: str = "") -> None:
        """Every class is served the cap: any class set is held."""

    def __repr__(self) -> str:
        return (f"ClassFreeTargets(T{self.cap.traction:+.3f} B{self.cap.braking:+.3f} for "
                f"{list(self._names)})")
