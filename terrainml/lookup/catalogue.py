"""Terrain catalogue: what each terrain class is, by name, for the desired-slip table (design §10).

A catalogue is a YAML file that gives every class of a class set either

* **terramechanics parameters** (``model: burckhardt`` tyre-road curve, or ``model: soil``:
  Bekker pressure-sinkage with Janosi-Hanamoto or Wong hump-type shear, the fields of
  :class:`terrainml.lookup.terramechanics.TerrainParams`), from which
  :meth:`terrainml.lookup.table.DesiredSlipTable.from_catalogue` computes the targets for a robot;
  or
* **direct targets** (``traction`` > 0, ``braking`` < 0, ``steady`` >= 0, SAE slip), served as
  given for any robot.

Every value carries a source: a reference (``docs/references.md`` key) or ``assumption: why``.
Layout::

    schema: terrainml.terrain_catalogue
    schema_version: 1
    name: reference
    description: ...
    classes:
      pavement:                       # the class name the models use, exactly
        model: burckhardt             # burckhardt | soil          (or: targets: {...})
        rigid_surface: true           # optional: the 0.10-0.20 traction rule applies
        summary: Burckhardt (1993) dry concrete   # optional one-line provenance
        params: {c1: 1.1973, c2: 25.168, c3: 0.5373, crr: 0.012}
        sources: {c1: Burckhardt (1993) dry concrete, ...}   # one per parameter / target

``friction_angle_deg`` may be given instead of ``friction_angle_rad``. Fields left out take the
defaults of ``TerrainParams``. Validation refuses, naming the file, the class and the field:
unknown or misplaced fields, missing required fields or sources, a bare ``assumption`` without
its reason, out-of-range values, targets that break the design §10 rules, and (when the caller
asks for a class set) missing classes. Built-in catalogues live in
``terrainml/lookup/catalogues/`` (``reference``, ``borealtc``).
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field, fields, replace
from importlib import resources
from pathlib import Path
from typing import Any, Sequence

import yaml

from terrainml._yaml_checks import YamlLimitError, load_bounded_yaml
from terrainml.lookup.catalogue_names import BUILTIN_CATALOGUES
from terrainml.lookup.target_rules import MAX_MAGNITUDE, MIN_TRACTION_MARGIN, RIGID_PEAK_RANGE
from terrainml.lookup.terrain_params import TerrainParams

__all__ = ["BUILTIN_CATALOGUES", "CatalogueClass", "CatalogueError", "TerrainCatalogue",
           "load_catalogue", "parse_catalogue"]

SCHEMA = "terrainml.terrain_catalogue"
SCHEMA_VERSION = 1
MODELS = ("burckhardt", "soil")
TARGET_NAMES = ("traction", "braking", "steady")

_DEG = math.pi / 180.0
_INF = math.inf
# field -> (low, high, low inclusive, high inclusive); units as in TerrainParams
_RANGES: dict[str, tuple[float, float, bool, bool]] = {
    "c1": (0.0, 3.0, False, True),
    "c2": (0.0, 1000.0, False, True),
    "c3": (0.0, 5.0, True, True),
    "crr": (0.0, 0.5, True, True),
    "cohesion_pa": (0.0, 1.0e6, True, True),
    "friction_angle_rad": (0.0, 60.0 * _DEG, True, True),
    "friction_angle_deg": (0.0, 60.0, True, True),
    "shear_modulus_m": (0.0, 0.5, False, True),
    "residual_ratio": (0.0, 1.0, False, True),
    "n_exp": (0.0, 2.5, False, True),
    "k_c": (0.0, 1.0e8, True, True),
    "k_phi": (0.0, 1.0e10, True, True),
    "layer_depth_m": (0.0, 0.5, True, True),
    "slip_sinkage": (0.0, 2.0, True, False),   # z(s) denominator 1 - 0.5 a |s| > 0 up to |s| = 1
    "free_slip": (0.0, 0.9, True, True),
    "lateral_mu": (0.0, 3.0, True, True),
    "lateral_alpha0_rad": (0.0, 1.6, False, True),
    "roughness_rms_m": (0.0, 0.1, True, True),
    "roughness_wavelength_min_m": (0.0, 100.0, False, True),
    "roughness_wavelength_max_m": (0.0, 100.0, False, True),
}
_CURVE_FIELDS = ("c1", "c2", "c3")         # the Burckhardt curve
_SIM_FIELDS = ("lateral_", "roughness_")   # used by the simulator only, allowed on every model
_REQUIRED = {"burckhardt": ("c1", "c2", "c3"),
             "soil": ("cohesion_pa", "friction_angle", "shear_modulus_m")}
_CLASS_KEYS = ("model", "params", "targets", "sources", "rigid_surface", "summary")
_TOP_KEYS = ("schema", "schema_version", "name", "description", "classes")


class CatalogueError(ValueError):
    """A terrain catalogue that cannot be read or breaks its schema (the message names the file)."""


@dataclass(frozen=True)
class CatalogueClass:
    """One class of a catalogue.

    Attributes
    ----------
    name : the class name, exactly as the models use it.
    params : TerrainParams for a terramechanics class, else None.
    targets : {"traction", "braking", "steady"} SAE slip for a direct-target class, else None.
    rigid_surface : the 0.10-0.20 traction rule of design §10 applies.
    sources : {field: reference or "assumption: why"}, one per given parameter or target.
    """

    name: str
    params: TerrainParams | None
    targets: dict[str, float] | None
    rigid_surface: bool
    sources: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class TerrainCatalogue:
    """A validated catalogue: classes in file order, with the file's name and content hash."""

    name: str
    classes: tuple[CatalogueClass, ...]
    source: str = "<catalogue>"
    sha256: str = ""
    description: str = ""

    @property
    def class_names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.classes)

    def select(self, class_names: Sequence[str] | None) -> tuple[CatalogueClass, ...]:
        """The classes in the order of ``class_names`` (all, in file order, when None).

        Raises CatalogueError naming the file and the classes it lacks.
        """
        if class_names is None:
            return self.classes
        want = [str(c) for c in class_names]
        dup = sorted({c for c in want if want.count(c) > 1})
        if dup:
            raise CatalogueError(f"{self.source}: class set names {dup} more than once")
        by_name = {c.name: c for c in self.classes}
        missing = [c for c in want if c not in by_name]
        if missing:
            raise CatalogueError(f"{self.source}: missing classes {missing} (the catalogue has "
                                 f"{list(self.class_names)}); add them to the catalogue")
        return tuple(by_name[c] for c in want)


# ----------------------------------------------------------------------------- YAML reading
class _UniqueKeyLoader(yaml.SafeLoader):
    """SafeLoader that refuses a key given twice (PyYAML silently keeps the last one)."""


def _mapping_without_duplicates(loader: yaml.SafeLoader, node: yaml.MappingNode) -> dict:
    seen: set = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node)
        if key in seen:
            raise yaml.constructor.ConstructorError(
                None, None, f"key {key!r} given twice", key_node.start_mark)
        seen.add(key)
    return loader.construct_mapping(node)


_UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG,
                                 _mapping_without_duplicates)


def _read(path: Path) -> tuple[Any, str]:
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise CatalogueError(f"{path}: cannot read the catalogue ({exc.strerror or exc})") from None
    try:
        text = raw.decode("utf-8")
        return load_bounded_yaml(text, _UniqueKeyLoader), hashlib.sha256(raw).hexdigest()
    except UnicodeDecodeError:
        raise CatalogueError(f"{path}: not a terrain catalogue (binary data, not UTF-8 YAML)") \
            from None
    except YamlLimitError as exc:
        raise CatalogueError(f"{path}: refused: {exc}") from None
    except yaml.YAMLError as exc:
        raise CatalogueError(f"{path}: not valid YAML ({exc})".replace("\n", " ")) from None


def load_catalogue(catalogue: "str | Path | TerrainCatalogue") -> TerrainCatalogue:
    """Read and validate a catalogue: a built-in name (``reference``, ``borealtc``) or a YAML path."""
    if isinstance(catalogue, TerrainCatalogue):
        return catalogue
    text = str(catalogue)
    if text in BUILTIN_CATALOGUES:
        ref = resources.files("terrainml.lookup").joinpath("catalogues", f"{text}.yaml")
        with resources.as_file(ref) as path:
            return _from_file(path, source=text)
    path = Path(text)
    if not path.is_file():
        raise CatalogueError(f"{text}: no such terrain catalogue file (built-in catalogues: "
                             f"{', '.join(BUILTIN_CATALOGUES)})")
    return _from_file(path, source=str(path))


def _from_file(path: Path, source: str) -> TerrainCatalogue:
    doc, sha = _read(path)
    return parse_catalogue(doc, source=source, sha256=sha)


# ----------------------------------------------------------------------------- validation
def parse_catalogue(doc: Any, source: str = "<catalogue>", sha256: str = "") -> TerrainCatalogue:
    """Validate a parsed catalogue document (see the module docstring for the layout)."""
    if not isinstance(doc, dict) or doc.get("schema") != SCHEMA:
        got = f"schema {doc.get('schema')!r}" if isinstance(doc, dict) else type(doc).__name__
        raise CatalogueError(f"{source}: not a terrain catalogue (expected a mapping with "
                             f"schema {SCHEMA!r}, got {got})")
    _no_unknown(doc, _TOP_KEYS, source)
    if doc.get("schema_version") != SCHEMA_VERSION:
        raise CatalogueError(f"{source}: schema_version {doc.get('schema_version')!r}, this "
                             f"terrainml reads {SCHEMA_VERSION}")
    classes = doc.get("classes")
    if not isinstance(classes, dict) or not classes:
        raise CatalogueError(f"{source}: field 'classes' must map class names to entries")
    parsed = tuple(_parse_class(name, entry, source) for name, entry in classes.items())
    if not sha256:
        sha256 = hashlib.sha256(json.dumps(doc, sort_keys=True, default=str).encode()).hexdigest()
    return TerrainCatalogue(name=str(doc.get("name") or Path(source).stem), classes=parsed,
                            source=source, sha256=sha256, description=str(doc.get("description")
                                                                          or ""))


def _no_unknown(d: dict, allowed: Sequence[str], where: str) -> None:
    unknown = [str(k) for k in d if k not in allowed]
    if unknown:
        raise CatalogueError(f"{where}: unknown field(s) {unknown}; allowed: {list(allowed)}")


def _number(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise CatalogueError(f"{where}: expected a number, got {value!r}")
    if not math.isfinite(float(value)):
        raise CatalogueError(f"{where}: must be finite, got {value!r}")
    return float(value)


def _check_range(key: str, value: float, where: str) -> None:
    lo, hi, lo_in, hi_in = _RANGES[key]
    ok = (value >= lo if lo_in else value > lo) and (value <= hi if hi_in else value < hi)
    if not ok:
        interval = f"{'[' if lo_in else '('}{lo:g}, {hi:g}{']' if hi_in else ')'}"
        raise CatalogueError(f"{where}: {value:g} out of range {interval}")


def _parse_class(name: Any, entry: Any, source: str) -> CatalogueClass:
    if not isinstance(name, str) or not name.strip():
        raise CatalogueError(f"{source}: class name {name!r} must be a non-empty string")
    where = f"{source}: class {name}"
    if not isinstance(entry, dict):
        raise CatalogueError(f"{where}: expected a mapping with params or targets")
    _no_unknown(entry, _CLASS_KEYS, where)
    has_p, has_t = "params" in entry, "targets" in entry
    if has_p == has_t:
        raise CatalogueError(f"{where}: give exactly one of 'params' (with 'model') or "
                             "'targets'")
    rigid = entry.get("rigid_surface", False)
    if not isinstance(rigid, bool):
        raise CatalogueError(f"{where}: field 'rigid_surface' must be true or false")
    sources = entry.get("sources")
    if not isinstance(sources, dict):
        raise CatalogueError(f"{where}: field 'sources' must map every parameter or target to "
                             "its reference or 'assumption: why'")
    if has_t:
        if "model" in entry:
            raise CatalogueError(f"{where}: field 'model' applies to 'params', not 'targets'")
        values = _parse_targets(entry["targets"], rigid, where)
        params = None
    else:
        params, values = _parse_params(name, entry, where)
    _check_sources(sources, values, where)
    if params is not None and "summary" in entry:
        params = _with_summary(params, entry["summary"], where)
    return CatalogueClass(name=name, params=params, targets=None if params else values,
                          rigid_surface=rigid, sources={k: str(v) for k, v in sources.items()})


def _check_sources(sources: dict, given: dict, where: str) -> None:
    extra = [str(k) for k in sources if k not in given]
    if extra:
        raise CatalogueError(f"{where}: sources name field(s) {extra} that the class does not "
                             "give")
    for key in given:
        src = sources.get(key)
        if not isinstance(src, str) or not src.strip():
            raise CatalogueError(f"{where}, field {key}: no source (give a reference or "
                                 "'assumption: why')")
        head, _, why = src.partition(":")
        if head.strip().lower() == "assumption" and not why.strip():
            raise CatalogueError(f"{where}, field {key}: an assumption needs its reason "
                                 "('assumption: why')")


def _parse_targets(targets: Any, rigid: bool, where: str) -> dict[str, float]:
    if not isinstance(targets, dict):
        raise CatalogueError(f"{where}: field 'targets' must map traction, braking, steady")
    _no_unknown(targets, TARGET_NAMES, f"{where}, targets")
    missing = [k for k in TARGET_NAMES if k not in targets]
    if missing:
        raise CatalogueError(f"{where}: targets lack {missing}")
    t = {k: _number(targets[k], f"{where}, field {k}") for k in TARGET_NAMES}
    if not 0.0 < t["traction"] <= MAX_MAGNITUDE:
        raise CatalogueError(f"{where}, field traction: {t['traction']:g} out of range "
                             f"(0, {MAX_MAGNITUDE}]")
    if not -MAX_MAGNITUDE <= t["braking"] < 0.0:
        raise CatalogueError(f"{where}, field braking: {t['braking']:g} out of range "
                             f"[-{MAX_MAGNITUDE}, 0)")
    if not 0.0 <= t["steady"] <= MAX_MAGNITUDE:
        raise CatalogueError(f"{where}, field steady: {t['steady']:g} out of range "
                             f"[0, {MAX_MAGNITUDE}]")
    if t["traction"] < t["steady"] + MIN_TRACTION_MARGIN - 1e-12:
        raise CatalogueError(f"{where}, field traction: {t['traction']:g} below steady "
                             f"{t['steady']:g} + {MIN_TRACTION_MARGIN} (design §10 rule)")
    lo, hi = RIGID_PEAK_RANGE
    if rigid and not lo <= t["traction"] <= hi:
        raise CatalogueError(f"{where}, field traction: {t['traction']:g} outside [{lo}, {hi}] "
                             "for a rigid surface (design §10 rule)")
    return t


def _parse_params(name: str, entry: dict, where: str) -> tuple[TerrainParams, dict[str, float]]:
    model = entry.get("model")
    if model not in MODELS:
        raise CatalogueError(f"{where}, field model: expected one of {list(MODELS)}, got "
                             f"{model!r}")
    raw = entry["params"]
    if not isinstance(raw, dict) or not raw:
        raise CatalogueError(f"{where}: field 'params' must map parameter names to numbers")
    # Bekker and shear fields mean nothing on a tyre-road curve, and c1..c3 nothing on a soil
    if model == "burckhardt":
        allowed = [k for k in _RANGES if k in _CURVE_FIELDS + ("crr",) or k.startswith(_SIM_FIELDS)]
    else:
        allowed = [k for k in _RANGES if k not in _CURVE_FIELDS]
    _no_unknown(raw, allowed, f"{where} (model {model}), params")
    if "friction_angle_deg" in raw and "friction_angle_rad" in raw:
        raise CatalogueError(f"{where}, field friction_angle_deg: give the angle once, in deg "
                             "or in rad")
    values = {str(k): _number(v, f"{where}, field {k}") for k, v in raw.items()}
    for key, value in values.items():
        _check_range(key, value, f"{where}, field {key}")
    for req in _REQUIRED[model]:
        if req == "friction_angle":
            if "friction_angle_deg" not in values and "friction_angle_rad" not in values:
                raise CatalogueError(f"{where}: missing field friction_angle_deg (or "
                                     "friction_angle_rad)")
        elif req not in values:
            raise CatalogueError(f"{where}: missing field {req} (required by model {model})")
    kwargs = dict(values)
    if "friction_angle_deg" in kwargs:
        kwargs["friction_angle_rad"] = kwargs.pop("friction_angle_deg") * _DEG
    lo_w = kwargs.get("roughness_wavelength_min_m", TerrainParams.roughness_wavelength_min_m)
    hi_w = kwargs.get("roughness_wavelength_max_m", TerrainParams.roughness_wavelength_max_m)
    if lo_w >= hi_w:
        raise CatalogueError(f"{where}, field roughness_wavelength_min_m: {lo_w:g} must be below "
                             f"roughness_wavelength_max_m {hi_w:g}")
    known = {f.name for f in fields(TerrainParams)}
    assert set(kwargs) <= known, set(kwargs) - known  # _RANGES lists TerrainParams fields only
    return TerrainParams(class_id=-1, name=name, model=model, **kwargs), values


def _with_summary(params: TerrainParams, summary: Any, where: str) -> TerrainParams:
    if not isinstance(summary, str):
        raise CatalogueError(f"{where}, field summary: expected a string")
    return replace(params, sources=summary)
