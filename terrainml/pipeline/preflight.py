"""The checks that can refuse ``terrainml train``'s data, run in seconds before any long work.

A refusal after the windows are cut, the models searched and the held-out runs replayed wastes
the user's half hour; every check that depends only on the runs' labels, their class names and
the options runs here, on the ingested run tables (or on a windows file's runs table):

* **runs per class**: grouped CV needs at least 2 classes with >= :data:`MIN_RUNS_PER_CLASS`
  runs, else refused (runs per class listed). A class with fewer runs is *data*, not an error:
  :data:`SINGLE_RUN_RULE` is applied and said in the report;
* **class names against the catalogue**: the desired-slip table of the classes
  (:func:`table_for_classes`). With ``--catalogue`` every class must be in it, else refused
  (the missing names and the catalogue's listed). Without, the first built-in catalogue with
  every class gives it; when none does (a team's own names), the model still trains and serves
  its classes, each with the class-free safe cap (:class:`~terrainml.lookup.table.
  ClassFreeTargets`), and the report says so (:data:`CLASS_FREE_RULE`);
* **sensors**: the window specs must be cuttable for the robot with the chosen sensor groups.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import pandas as pd

from terrainml.classes import TERRAIN_CLASSES
from terrainml.features.windows import window_spec
from terrainml.lookup.catalogue import BUILTIN_CATALOGUES
from terrainml.lookup.table import DesiredSlipTable
from terrainml.pipeline.dataset import run_class
from terrainml.robot import RobotSpec

__all__ = ["Preflight", "check_runs", "check_tables", "check_dataset", "table_for_classes", "class_names_of_tables",
           "MIN_RUNS_PER_CLASS",
           "SINGLE_RUN_RULE", "CLASS_FREE_RULE"]

#: fewer runs than this and grouped CV never tests the class on a run it was not trained on
MIN_RUNS_PER_CLASS = 2
#: the rule for a class with fewer runs than grouped CV needs (report and warning)
SINGLE_RUN_RULE = ("trained on, not scored: kept in the final model; left out of the cross-validation, of the "
                   "selection and of the served replay (no fold holds out its only run, so no fold model is "
                   "asked to serve a class it never saw)")
#: the rule for class names no catalogue describes (report and warning)
CLASS_FREE_RULE = ("no terrain parameters: the model classifies and serves these classes by name, each with the "
                   "class-free safe cap of the reference catalogue as its desired slip (design §10), flagged on "
                   "every tick, until a catalogue with them is given (`--catalogue CAT.yaml`)")


@dataclass
class Preflight:
    """What the checks found (all of it goes into the report).

    Attributes
    ----------
    runs_per_class : {class name: runs}.
    class_names : the class names by id (the table's ids).
    table : the desired-slip table of the classes, or None (no catalogue has them: class-free).
    catalogue : the catalogue the table comes from (``reference``, ``borealtc``, a path) or None.
    rules : {class name: the rule applied to it} (a class with a single run).
    """

    runs_per_class: dict
    class_names: list
    table: Any = None
    catalogue: str | None = None
    rules: dict = field(default_factory=dict)

    def doc(self) -> dict:
        """The report's ``preflight`` entry."""
        return {"runs_per_class": dict(self.runs_per_class), "catalogue": self.catalogue,
                "class_free": self.table is None, "rules": dict(self.rules),
                "desired_slip": (CLASS_FREE_RULE if self.table is None else
                                 f"the `{self.catalogue}` terrain catalogue's table of the classes")}


def class_names_of_tables(tables: Sequence[pd.DataFrame]) -> list[str]:
    """Class names by id of ingested run tables: their metadata's ``classes``, else ours."""
    for t in tables:
        meta = t.attrs.get("terrainml", {}) if hasattr(t, "attrs") else {}
        if isinstance(meta, dict) and meta.get("classes"):
            return [str(c) for c in meta["classes"]]
    return list(TERRAIN_CLASSES)


def table_for_classes(robot: RobotSpec, names: Sequence[str], catalogue: str | None = None
                      ) -> tuple[DesiredSlipTable | None, str | None]:
    """(desired-slip table of the classes ``names`` (ids = positions), its catalogue) or (None, None).

    ``catalogue`` (a YAML path or a built-in name) must hold every class: ValueError naming
    ``--catalogue``, the missing classes and the catalogue's otherwise. Without it: our eight
    classes get :meth:`DesiredSlipTable.build`, others the first built-in catalogue with all of
    them, else None (class-free serving).
    """
    names = [str(n) for n in names]
    if catalogue is not None:
        try:
            return DesiredSlipTable.from_catalogue(catalogue, robot, names), str(catalogue)
        except Exception as exc:  # noqa: BLE001 - CatalogueError/LookupTableError/OSError: one message
            raise ValueError(f"--catalogue {catalogue}: no desired-slip table for the data's classes {names} "
                             f"({exc})") from None
    if names == list(TERRAIN_CLASSES):
        try:
            return DesiredSlipTable.build(robot), "reference"
        except Exception:  # noqa: BLE001 - a robot the terramechanics cannot build for: class-free
            return None, None
    for cat in BUILTIN_CATALOGUES:
        try:
            return DesiredSlipTable.from_catalogue(cat, robot, names), str(cat)
        except Exception:  # noqa: BLE001 - a catalogue without these classes: try the next
            continue
    return None, None


def _runs_per_class(labels: Sequence[int], names: Sequence[str]) -> dict[str, int]:
    out: dict[str, int] = {}
    for c in sorted(int(c) for c in labels if int(c) >= 0):
        n = names[c] if 0 <= c < len(names) else str(c)
        out[n] = out.get(n, 0) + 1
    return out


def check_runs(labels: Sequence[int], names: Sequence[str], robot: RobotSpec, *, catalogue: str | None = None,
               specs: Sequence[Any] = (), sensors: Sequence[str] | None = None,
               say: Callable[[str], None] | None = None) -> Preflight:
    """Every check of the module docstring; ValueError (the message names the option or lists the
    runs per class) on data that cannot be trained, warnings through ``say``.

    Parameters
    ----------
    labels : the class id of every run (:func:`~terrainml.pipeline.dataset.run_class`; -1 unlabelled).
    names : class names by id. robot : RobotSpec. catalogue : ``--catalogue`` or None.
    specs : window specs (or their names) the training may cut (one must be cuttable with ``sensors``).
    sensors : sensor groups the model may use (None: all).
    say : callback for warnings (``warning: ...``).
    """
    say = say or (lambda msg: None)
    per = _runs_per_class(labels, names)
    if not per:
        raise ValueError("no run has a terrain label: nothing to train on (the runs need a per-row `terrain` "
                         "column, or a labelled dataset format)")
    cv = [n for n, k in per.items() if k >= MIN_RUNS_PER_CLASS]
    if len(cv) < 2:
        raise ValueError(f"grouped CV needs at least 2 classes with >= {MIN_RUNS_PER_CLASS} runs; runs per class: "
                         f"{per}; record more runs")
    rules = {}
    for n, k in per.items():
        if k < MIN_RUNS_PER_CLASS:
            rules[n] = f"{k} run: {SINGLE_RUN_RULE}"
            say(f"warning: class {n!r} has {k} run: {SINGLE_RUN_RULE}")
    if specs:
        why = {}
        for s in specs:
            try:
                (window_spec(s) if isinstance(s, str) else s).resolve(robot, sensors)
            except ValueError as exc:
                why[getattr(s, "name", s)] = str(exc)
        if len(why) == len(specs):
            raise ValueError(f"--sensors/--windows: no window spec can be cut for robot '{robot.name}'"
                             + (f" with sensors {list(sensors)}" if sensors else "") + ": "
                             + "; ".join(f"{s}: {r}" for s, r in why.items()))
    present = list(per)
    table, source = table_for_classes(robot, names, catalogue)
    if table is None:
        say(f"warning: no built-in terrain catalogue ({', '.join(map(str, BUILTIN_CATALOGUES))}) has the classes "
            f"{present}: {CLASS_FREE_RULE}")
    return Preflight(per, list(names), table, source, rules)


def check_tables(tables: Sequence[pd.DataFrame], robot: RobotSpec, **kw: Any) -> Preflight:
    """:func:`check_runs` of ingested run tables (their labels and class names); ``kw`` as there."""
    return check_runs([run_class(t) for t in tables], class_names_of_tables(tables), robot, **kw)


def check_dataset(ds: Any, **kw: Any) -> Preflight:
    """:func:`check_runs` of a windows file's Dataset (its runs table and class names)."""
    runs = ds.runs
    labels = runs.loc[runs["n_rows"] > 0, "run_class"].tolist() if len(runs) else []
    names = ds.windows.attrs.get("all_class_names")
    if names is None:
        names = list(TERRAIN_CLASSES)
    return check_runs(labels, list(names), ds.robot, **kw)
