"""Dataset specs: a YAML that says how a multi-file CSV/Parquet dataset reaches the run table (design §5).

A spec names the files of one run and how they pair (patterns with ``{fields}``, e.g.
``{label}/pro_{run}.csv`` and ``{label}/imu_{run}.csv``: files whose fields agree are one run),
each file's time column and unit, each column's canonical column with its unit and scale (m/s
wheel speeds become rad/s through the robot's wheel radius, deg becomes rad), which wheels one
side's column feeds (a skid-steer Husky: left -> wheels 1 and 3), where the label comes from (a
folder name, a column, or a file listing runs and labels), the label names, and the robot spec.
The files then go through the tabular path of the one ingest engine
(:mod:`terrainml.io.ingest.tables`); :func:`terrainml.io.ingest.load_run` with ``dataset=``
reads one run, :func:`terrainml.io.ingest.load_dataset` a whole folder.

Built-in specs live in ``terrainml/io/datasets/*.yaml`` (``borealtc``). Every field is documented
in docs/io.md ("Dataset specs"). Errors name the spec file and the entry, or the data file and
its column.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from terrainml._yaml_checks import read_builtin_yaml, read_yaml_file
from terrainml.io.dataset_spec_names import BUILTIN_SPECS
from terrainml.io.ingest.tables import SPANS, Binding, TableFile, label_values, table_header
from terrainml.robot import RobotSpec
from terrainml.schema import column_map

LABEL_SOURCES = ("folder", "column", "file", "none")
_FIELD = re.compile(r"\{(\w+)\}")
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
# source unit -> factor to the canonical unit, per canonical unit (taken from the column's suffix)
UNITS: dict[str, dict[str, float]] = {
    "rad/s": {"rad/s": 1.0, "deg/s": math.pi / 180.0, "rpm": 2.0 * math.pi / 60.0},
    "rad": {"rad": 1.0, "deg": math.pi / 180.0},
    "m/s^2": {"m/s^2": 1.0, "g": 9.80665},
    "m/s": {"m/s": 1.0, "km/h": 1.0 / 3.6},
    "A": {"A": 1.0, "mA": 1e-3},
    "-": {"-": 1.0},
}
_SUFFIX_UNIT = (("_radps", "rad/s"), ("_rad", "rad"), ("_mps2", "m/s^2"), ("_mps", "m/s"), ("_a", "A"))


class DatasetSpecError(ValueError):
    """A dataset spec or a dataset's file cannot be used (the message names the file and entry)."""


@dataclass(frozen=True)
class ColumnSpec:
    """One column of a file: its name (and aliases) in the file, the canonical column it feeds."""

    name: str
    to: str                                  # canonical column, or a template with {i} (per wheel)
    wheels: tuple[int, ...] | None = None    # for {i}: the wheels this column feeds
    unit: str | None = None                  # the file's unit (None: already canonical)
    scale: float = 1.0
    offset: float = 0.0
    aliases: tuple[str, ...] = ()
    resample: str | None = None              # linear | previous (None: by canonical column)
    optional: bool = False


@dataclass(frozen=True)
class FileSpec:
    """One file of a run."""

    role: str
    pattern: str
    fmt: str | None = None                   # csv | parquet (None: from the extension)
    time_column: str = "time"
    time_aliases: tuple[str, ...] = ()
    time_scale: float = 1.0                  # to seconds
    gap_periods: float = 2.0
    columns: tuple[ColumnSpec, ...] = ()
    optional: bool = False

    def regex(self) -> re.Pattern:
        out, pos = "", 0
        for m in _FIELD.finditer(self.pattern):
            out += re.escape(self.pattern[pos:m.start()]) + f"(?P<{m.group(1)}>[^/]+?)"
            pos = m.end()
        return re.compile(out + re.escape(self.pattern[pos:]))

    def glob(self) -> str:
        return _FIELD.sub("*", self.pattern)

    def format_of(self, path: Path) -> str:
        return self.fmt or ("parquet" if path.suffix.lower() in (".parquet", ".pq") else "csv")


@dataclass(frozen=True)
class LabelSpec:
    source: str = "none"                     # folder | column | file | none
    field: str = "label"                     # folder: the pattern field holding the label
    file: str | None = None                  # column: the role of the file holding the column
    column: str | None = None                # column / file: the label column
    path: str | None = None                  # file: table of run -> label (relative to the dataset root)
    key: str = "run"                         # file: its column holding the run field
    names: tuple[str, ...] | None = None     # class names (ids are their order); None: sorted found
    unlabelled: tuple[str, ...] = ("-1",)


@dataclass(frozen=True)
class RunFiles:
    """The files of one run."""

    run_id: str
    fields: dict[str, str]
    files: dict[str, Path | None]            # role -> path (None: an optional file absent)
    root: Path

    @property
    def primary(self) -> Path:
        return next(p for p in self.files.values() if p is not None)


@dataclass
class DatasetSpec:
    name: str
    files: list[FileSpec]
    label: LabelSpec = field(default_factory=LabelSpec)
    sides: dict[str, tuple[int, ...]] = field(default_factory=dict)
    robot: str | None = None
    rate_hz: float | None = None
    span: str = "overlap"
    run_id: str | None = None                # template over the pattern fields
    source_file: str = "<dict>"
    doc: dict[str, Any] = field(default_factory=dict)

    # ------------------------------------------------------------------ runs
    def _run(self, root: Path, fields: dict[str, str], first: Path) -> RunFiles:
        files: dict[str, Path | None] = {self.files[0].role: first}
        for f in self.files[1:]:
            p = root / f.pattern.format(**fields)
            files[f.role] = p if p.is_file() else None
        rid = (self.run_id or "_".join("{" + k + "}" for k in fields)).format(**fields)
        return RunFiles(rid, dict(fields), files, root)

    def discover(self, root: str | Path) -> list[RunFiles]:
        """Every run under ``root``: each match of the first file's pattern, its other files paired
        by the pattern fields (sorted by path)."""
        root = Path(root)
        if not root.is_dir():
            raise DatasetSpecError(f"{root}: not a folder (dataset spec '{self.name}' expects "
                                   f"{', '.join(f.pattern for f in self.files)})")
        first = self.files[0]
        rx = first.regex()
        runs = []
        for p in sorted(root.glob(first.glob())):
            m = rx.fullmatch(p.relative_to(root).as_posix())
            if m and p.is_file():
                runs.append(self._run(root, m.groupdict(), p))
        if not runs:
            raise DatasetSpecError(f"{root}: no {first.pattern} files found (dataset spec '{self.name}')")
        return runs

    def run_of(self, path: str | Path) -> RunFiles:
        """The run a file belongs to (any of the spec's files), and so the dataset root."""
        path = Path(path)
        if not path.is_absolute() and len(path.parts) <= max(f.pattern.count("/") for f in self.files):
            path = path.absolute()   # a file named from inside its folder: its folders are the fields
        for f in self.files:
            depth = f.pattern.count("/") + 1
            if len(path.parts) < depth:
                continue
            tail = Path(*path.parts[-depth:]).as_posix()
            m = f.regex().fullmatch(tail)
            if m:
                root = Path(*path.parts[:-depth]) if len(path.parts) > depth else Path(".")
                fields = m.groupdict()
                first = root / self.files[0].pattern.format(**fields)
                if not first.is_file():
                    raise DatasetSpecError(f"{path}: its run's {self.files[0].role} file {first} is missing")
                return self._run(root, fields, first)
        raise DatasetSpecError(f"{path}: matches none of dataset spec '{self.name}''s files "
                               f"({', '.join(f.pattern for f in self.files)})")

    # ------------------------------------------------------------------ labels
    def run_label(self, run: RunFiles) -> str | None:
        """The label of a run (folder or file labels; None for column labels or none)."""
        lab = self.label
        if lab.source == "folder":
            return run.fields[lab.field]
        if lab.source == "file":
            table = self._label_table(run.root)
            key = run.fields.get(lab.key)
            if key not in table:
                raise DatasetSpecError(f"{run.root / lab.path}: no label for run {key!r} (column '{lab.key}')")
            return table[key]
        return None

    def _label_table(self, root: Path) -> dict[str, str]:
        p = root / self.label.path
        try:
            df = pd.read_csv(p, dtype=str, keep_default_na=False) if p.suffix.lower() != ".parquet" \
                else pd.read_parquet(p).astype(str)
        except Exception as exc:  # noqa: BLE001 - parser errors of several types
            raise DatasetSpecError(f"{p}: label file not readable ({exc})") from None
        for c in (self.label.key, self.label.column):
            if c not in df.columns:
                raise DatasetSpecError(f"{p}: missing column '{c}' (have: {', '.join(df.columns)})")
        return dict(zip(df[self.label.key].str.strip(), df[self.label.column].str.strip()))

    def label_names(self, runs: list[RunFiles]) -> list[str] | None:
        """The class names: the spec's, else the sorted labels found in ``runs`` (None: no labels).
        A label that is not among the spec's names is an error naming the file and the value."""
        lab = self.label
        if lab.source == "none":
            return None
        if lab.source == "column":
            found: set[str] = set()
            if lab.names is None:
                for run in runs:
                    p = run.files.get(lab.file)
                    if p is not None:
                        tf = TableFile(p, self._file(lab.file).format_of(p), unlabelled=lab.unlabelled)
                        found |= set(label_values(tf, self.resolve_columns(self._file(lab.file), p,
                                                                    [lab.column])[lab.column]))
            return list(lab.names) if lab.names is not None else sorted(found)
        labels: dict[str, RunFiles] = {}
        for r in runs:   # each label with the first run that has it
            labels.setdefault(self.run_label(r), r)
        if lab.names is None:
            return sorted(labels)
        for value, run in labels.items():
            if value not in lab.names:
                raise DatasetSpecError(f"{run.primary}: label {value!r} (from the {lab.source}) is not one of "
                                       f"the label names {list(lab.names)} of dataset spec '{self.name}'")
        return list(lab.names)

    # ------------------------------------------------------------------ files -> table files
    def _file(self, role: str) -> FileSpec:
        return next(f for f in self.files if f.role == role)

    @staticmethod
    def resolve_columns(f: FileSpec, path: Path, wanted: list[str], aliases: dict[str, tuple[str, ...]] | None = None,
                 optional: set[str] | None = None) -> dict[str, str]:
        """Spec column names -> the file's own names (case and surrounding spaces ignored, aliases
        tried in order); a required column that is absent raises, naming the file and column."""
        try:
            header = table_header(path, f.format_of(path))
        except Exception as exc:  # noqa: BLE001 - parser errors of several types
            raise DatasetSpecError(f"{path}: not a readable {f.format_of(path).upper()} file ({exc})") from None
        lower = {h.strip().lower(): h for h in header}
        out = {}
        for name in wanted:
            cands = (name, *(aliases or {}).get(name, ()))
            hit = next((lower[c.strip().lower()] for c in cands if c.strip().lower() in lower), None)
            if hit is None:
                if optional and name in optional:
                    continue
                raise DatasetSpecError(f"{path}: missing column '{name}' (have: {', '.join(header)})")
            out[name] = hit
        return out

    def table_files(self, run: RunFiles, robot: RobotSpec, label_names: list[str] | None) -> list[TableFile]:
        """The run's files as :class:`TableFile` s for the tabular ingest path."""
        out = []
        for f in self.files:
            p = run.files.get(f.role)
            if p is None:
                continue
            wanted = [f.time_column] + [c.name for c in f.columns]
            aliases = {f.time_column: f.time_aliases, **{c.name: c.aliases for c in f.columns}}
            label_col = self.label.column if self.label.source == "column" and self.label.file == f.role else None
            if label_col:
                wanted.append(label_col)
            names = self.resolve_columns(f, p, wanted, aliases, {c.name for c in f.columns if c.optional})
            bindings = {}
            for c in f.columns:
                if c.name not in names:
                    continue
                factor = self._unit_factor(c, robot)
                for canon in self._targets(c):
                    bindings[canon] = Binding(names[c.name], c.scale * factor, c.offset, c.resample)
            if label_col:
                bindings["terrain"] = Binding(names[label_col])
            out.append(TableFile(p, f.format_of(p), role=f.role, time_column=names[f.time_column],
                                 time_scale=f.time_scale, bindings=bindings, pass_through=False,
                                 gap_periods=f.gap_periods, label_names=label_names if label_col else None,
                                 unlabelled=self.label.unlabelled, name_by_source=True))
        return out

    def absent_columns(self, run: RunFiles, robot: RobotSpec) -> list[str]:
        """Canonical columns of the run's absent optional files (kept as NaN, group invalid)."""
        return [t for f in self.files if run.files.get(f.role) is None for c in f.columns for t in self._targets(c)]

    def _targets(self, c: ColumnSpec) -> list[str]:
        if "{i}" not in c.to:
            return [c.to]
        return [c.to.replace("{i}", str(i)) for i in c.wheels]

    def _unit_factor(self, c: ColumnSpec, robot: RobotSpec) -> float:
        if c.unit is None:
            return 1.0
        canon = c.to.replace("{i}", "1")
        if canon.endswith("_omega_radps") and c.unit == "m/s":
            return 1.0 / robot.wheel_radius_m   # the wheel's rim speed -> its angular speed
        return UNITS[canonical_unit(canon)][c.unit]

    def to_dict(self) -> dict[str, Any]:
        return dict(self.doc)


# ----------------------------------------------------------------------------- parsing
def canonical_unit(column: str) -> str:
    for suffix, unit in _SUFFIX_UNIT:
        if column.endswith(suffix):
            return unit
    return "-"


def _tuple(x, where: str) -> tuple:
    if x is None:
        return ()
    if isinstance(x, (str, int)):
        return (x,)
    if not isinstance(x, list):
        raise DatasetSpecError(f"{where}: expected a list, got {x!r}")
    return tuple(x)


def _number(x, where: str) -> float:
    try:
        v = float(x)
    except (TypeError, ValueError):
        raise DatasetSpecError(f"{where}: expected a number, got {x!r}") from None
    if not math.isfinite(v):
        raise DatasetSpecError(f"{where}: expected a finite number, got {x!r}")
    return v


def _column(name: str, c: Any, sides: dict[str, tuple[int, ...]], where: str) -> ColumnSpec:
    if isinstance(c, str):
        c = {"to": c}
    if not isinstance(c, dict) or "to" not in c:
        raise DatasetSpecError(f"{where}: column {name!r} needs 'to' (a canonical column)")
    extra = set(c) - {"to", "wheels", "unit", "scale", "offset", "aliases", "resample", "optional"}
    if extra:
        raise DatasetSpecError(f"{where}: column {name!r}: unknown field(s) {sorted(extra)}")
    to = str(c["to"])
    probe = to.replace("{i}", "1")
    if probe not in column_map(1) and not re.fullmatch(r"wheel\d+_(omega_radps|steer_rad|current_a|cmd_omega_radps)",
                                                      probe):
        raise DatasetSpecError(f"{where}: column {name!r}: {to!r} is not a canonical column (design §5)")
    if probe in ("t_s", "run_id", "terrain") or probe.endswith("_valid"):
        raise DatasetSpecError(f"{where}: column {name!r}: {to!r} is set by the spec itself "
                               "(time:, label:), not by a column")
    wheels = None
    if "{i}" in to:
        w = c.get("wheels")
        if w is None:
            raise DatasetSpecError(f"{where}: column {name!r}: {to!r} needs 'wheels' (a side name or wheel numbers)")
        if isinstance(w, str):
            if w not in sides:
                raise DatasetSpecError(f"{where}: column {name!r}: side {w!r} is not in 'sides' ({sorted(sides)})")
            wheels = sides[w]
        else:
            wheels = tuple(int(_number(i, f"{where}: column {name!r}: wheels")) for i in _tuple(w, where))
        if not wheels or min(wheels) < 1:
            raise DatasetSpecError(f"{where}: column {name!r}: wheels must be wheel numbers 1..N")
    elif "wheels" in c:
        raise DatasetSpecError(f"{where}: column {name!r}: 'wheels' needs a {{i}} template in 'to'")
    unit = c.get("unit")
    if unit is not None:
        unit = str(unit)
        cu = canonical_unit(probe)
        ok = set(UNITS[cu]) | ({"m/s"} if probe.endswith("_omega_radps") else set())
        if unit not in ok:
            raise DatasetSpecError(f"{where}: column {name!r}: unit {unit!r} cannot become {cu} "
                                   f"(known: {', '.join(sorted(ok))})")
    resample = c.get("resample")
    if resample not in (None, "linear", "previous"):
        raise DatasetSpecError(f"{where}: column {name!r}: resample must be linear or previous")
    return ColumnSpec(str(name), to, wheels, unit, _number(c.get("scale", 1.0), f"{where}: {name}: scale"),
                      _number(c.get("offset", 0.0), f"{where}: {name}: offset"),
                      tuple(str(a) for a in _tuple(c.get("aliases"), where)), resample, bool(c.get("optional", False)))


def _file(role: str, f: Any, sides, where: str) -> FileSpec:
    if not isinstance(f, dict) or "pattern" not in f:
        raise DatasetSpecError(f"{where}: file {role!r} needs 'pattern' (e.g. '{{label}}/{role}_{{run}}.csv')")
    extra = set(f) - {"pattern", "format", "time", "gap_periods", "columns", "optional"}
    if extra:
        raise DatasetSpecError(f"{where}: file {role!r}: unknown field(s) {sorted(extra)}")
    fmt = f.get("format")
    if fmt not in (None, "csv", "parquet"):
        raise DatasetSpecError(f"{where}: file {role!r}: format must be csv or parquet")
    time = f.get("time", {"column": "time"})
    if isinstance(time, str):
        time = {"column": time}
    if not isinstance(time, dict) or "column" not in time:
        raise DatasetSpecError(f"{where}: file {role!r}: 'time' needs 'column'")
    unit = time.get("unit", "s")
    if unit not in TIME_UNITS:
        raise DatasetSpecError(f"{where}: file {role!r}: time unit must be one of {', '.join(TIME_UNITS)}")
    scale = TIME_UNITS[unit] * _number(time.get("scale", 1.0), f"{where}: file {role!r}: time scale")
    cols = f.get("columns") or {}
    if not isinstance(cols, dict) or not cols:
        raise DatasetSpecError(f"{where}: file {role!r} needs 'columns' (file column -> canonical column)")
    gap = _number(f.get("gap_periods", 2.0), f"{where}: file {role!r}: gap_periods")
    if gap < 1.0:
        raise DatasetSpecError(f"{where}: file {role!r}: gap_periods must be >= 1")
    return FileSpec(str(role), str(f["pattern"]), fmt, str(time["column"]),
                    tuple(str(a) for a in _tuple(time.get("aliases"), where)), scale, gap,
                    tuple(_column(n, c, sides, f"{where}: file {role!r}") for n, c in cols.items()),
                    bool(f.get("optional", False)))


def _label(d: Any, roles: list[str], fields: set[str], where: str) -> LabelSpec:
    if d is None:
        return LabelSpec()
    if not isinstance(d, dict) or d.get("from") not in LABEL_SOURCES:
        raise DatasetSpecError(f"{where}: 'label' needs 'from' ({' | '.join(LABEL_SOURCES)})")
    src = d["from"]
    names = d.get("names")
    if names is not None:
        names = tuple(str(n) for n in _tuple(names, f"{where}: label names"))
        if len(set(names)) != len(names):
            raise DatasetSpecError(f"{where}: label names repeat a name")
    lab = LabelSpec(src, str(d.get("field", "label")), d.get("file"), d.get("column"), d.get("path"),
                    str(d.get("key", "run")), names,
                    tuple(str(u) for u in _tuple(d.get("unlabelled", ["-1"]), where)))
    if src == "folder" and lab.field not in fields:
        raise DatasetSpecError(f"{where}: label from folder: field '{{{lab.field}}}' is not in the first "
                               "file's pattern")
    if src == "column" and (lab.file not in roles or not lab.column):
        raise DatasetSpecError(f"{where}: label from column needs 'file' (one of {roles}) and 'column'")
    if src == "file" and (not lab.path or not lab.column or lab.key not in fields):
        raise DatasetSpecError(f"{where}: label from file needs 'path', 'column' and 'key' "
                               "(a field of the first file's pattern)")
    return lab


def _outside(rel: str) -> bool:
    """A spec path (pattern, label file) that leaves the dataset folder: absolute or with ``..``."""
    p = Path(rel)
    return p.is_absolute() or rel.startswith("~") or ".." in p.parts


def _check_inside(spec: "DatasetSpec", allow_outside: bool) -> None:
    """Refuse a pattern or label file outside the dataset folder unless ``allow_outside``."""
    if allow_outside:
        return
    paths = [(f"file {f.role!r} pattern", f.pattern) for f in spec.files]
    if spec.label.path:
        paths.append(("label path", spec.label.path))
    for what, rel in paths:
        if _outside(rel):
            raise DatasetSpecError(f"{spec.source_file}: {what} {rel!r} reads outside the dataset "
                                   "folder; refused (allow it with --allow-outside-spec-dir)")


def parse_dataset_spec(data: Any, source: str = "<dict>", *, allow_outside: bool = False) -> DatasetSpec:
    """Validate a spec document (the YAML's content).

    A file pattern or label path that leaves the dataset folder (absolute, ``~`` or ``..``, e.g.
    ``../imu_{run}.csv``) is refused unless ``allow_outside`` (the CLI's
    ``--allow-outside-spec-dir``): a spec from elsewhere must not read files outside the data.
    """
    if not isinstance(data, dict):
        raise DatasetSpecError(f"{source}: a dataset spec must be a mapping")
    extra = set(data) - {"name", "description", "robot", "rate_hz", "span", "run_id", "files", "sides", "label"}
    if extra:
        raise DatasetSpecError(f"{source}: unknown field(s) {sorted(extra)}")
    sides_doc = data.get("sides") or {}
    if not isinstance(sides_doc, dict):
        raise DatasetSpecError(f"{source}: 'sides' must map a side name to wheel numbers")
    sides = {str(k): tuple(int(_number(i, f"{source}: sides.{k}")) for i in _tuple(v, source))
             for k, v in sides_doc.items()}
    files_doc = data.get("files")
    if not isinstance(files_doc, dict) or not files_doc:
        raise DatasetSpecError(f"{source}: 'files' must map a file role to its pattern and columns")
    files = [_file(r, f, sides, source) for r, f in files_doc.items()]
    if files[0].optional:
        raise DatasetSpecError(f"{source}: the first file ({files[0].role}) defines the runs: it cannot be optional")
    fields = set(_FIELD.findall(files[0].pattern))
    for f in files[1:]:
        if set(_FIELD.findall(f.pattern)) - fields:
            raise DatasetSpecError(f"{source}: file {f.role!r}: pattern fields must be among the first file's "
                                   f"{sorted(fields)}")
    span = data.get("span", "overlap")
    if span not in SPANS:
        raise DatasetSpecError(f"{source}: 'span' must be one of {', '.join(SPANS)}")
    rate = data.get("rate_hz")
    if rate is not None and _number(rate, f"{source}: rate_hz") <= 0:
        raise DatasetSpecError(f"{source}: rate_hz must be positive")
    run_id = data.get("run_id")
    if run_id is not None and set(_FIELD.findall(str(run_id))) - fields:
        raise DatasetSpecError(f"{source}: run_id uses fields not in the first file's pattern {sorted(fields)}")
    spec = DatasetSpec(name=str(data.get("name", Path(source).stem)), files=files,
                       label=_label(data.get("label"), [f.role for f in files], fields, source), sides=sides,
                       robot=None if data.get("robot") is None else str(data["robot"]),
                       rate_hz=None if rate is None else float(rate), span=span,
                       run_id=None if run_id is None else str(run_id), source_file=source, doc=dict(data))
    _check_inside(spec, allow_outside)
    return spec


def load_dataset_spec(spec: str | Path | DatasetSpec | dict, *, allow_outside: bool = False) -> DatasetSpec:
    """A spec: a built-in name (``borealtc``), a YAML path, a parsed dict or a DatasetSpec.

    ``allow_outside``: accept patterns outside the dataset folder (:func:`parse_dataset_spec`)."""
    if isinstance(spec, DatasetSpec):
        return spec
    if isinstance(spec, dict):
        return parse_dataset_spec(spec, allow_outside=allow_outside)
    name = str(spec)
    if name in BUILTIN_SPECS:
        return parse_dataset_spec(read_builtin_yaml("terrainml.io", "datasets", name), f"{name}.yaml")
    path = Path(name)
    data = read_yaml_file(path, DatasetSpecError,
                          f"{path}: dataset spec not found (built-in: {', '.join(BUILTIN_SPECS)})")
    spec_ = parse_dataset_spec(data, str(path), allow_outside=allow_outside)
    if spec_.robot is not None and not Path(spec_.robot).is_absolute() and spec_.robot.endswith((".yaml", ".yml")):
        spec_.robot = str(path.parent / spec_.robot)   # a robot spec next to the dataset spec
    return spec_
