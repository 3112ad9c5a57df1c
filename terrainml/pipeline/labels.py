"""Label a run that was recorded unlabelled: ``terrainml dataset label``.

``terrainml predict --record-unknown DIR`` writes every stretch of unknown ground as a run table
(Parquet, ``terrain`` = -1) with the model's class names in its metadata (``classes``: the class
of id i is ``classes[i]``) and a JSON sidecar. :func:`label_run` gives such a run (or any run
table) one class for all its rows: a name already in ``classes`` gets its id; a new name is
appended (the next free id), so the class list of the run still names every id. The sidecar,
when there is one, gets ``label``. ``terrainml dataset build`` then takes a folder of such runs
with the other runs (Parquet) like any labelled run.

A run recorded as MCAP (``--record-format mcap``) is not labelled in place: an MCAP's
``/terrain/label`` carries bare class ids, read against the built-in class list, so neither the
model's class ids nor a new name would survive; :func:`label_run` refuses it (and any other
non-Parquet file) with the two commands to run instead: ``terrainml ingest RUN.mcap --robot R
--out RUN.parquet`` (beside the sidecar), then label that Parquet run. A run table without
``classes`` in its metadata (such an ingested MCAP) takes the class list of its sidecar.
"""

from __future__ import annotations

import json
import shlex
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from terrainml.atomic import write_text
from terrainml.classes import TERRAIN_CLASSES
from terrainml.schema import read_run_parquet, table_metadata, write_run_parquet

__all__ = ["label_run", "Labelled"]


@dataclass
class Labelled:
    """What :func:`label_run` wrote: the run file, the class id and name, the run's class list,
    the sidecar written (None without one), whether the name was added as a new class."""

    path: Path
    class_id: int
    name: str
    classes: list
    sidecar: Path | None
    added: bool = False


def label_run(path: str | Path, terrain: str, out: str | Path | None = None) -> Labelled:
    """Set every row's ``terrain`` of the run table ``path`` to the class ``terrain``; write ``out``.

    Parameters
    ----------
    path : a run table written by :func:`terrainml.schema.write_run_parquet` (``--record-unknown``,
        or ``terrainml ingest`` of an MCAP one).
    terrain : a class name (of the run's ``classes``: its metadata's, else its sidecar's, else
        the built-in list; else appended as a new class) or a class id of that list.
    out : the labelled run (default: ``path``, replaced whole); its sidecar goes beside it.

    Raises
    ------
    SchemaError naming the file that is not a run table; ValueError naming the id out of the
    run's class list, or an empty name, or a log that is not Parquet (an MCAP run: the message
    gives the ``terrainml ingest`` command to run first).
    """
    path = Path(path)
    out = Path(out) if out is not None else path
    side = _read_sidecar(path)
    if path.suffix.lower() != ".parquet":
        raise ValueError(_not_parquet(path, terrain, side))
    df = read_run_parquet(path)
    meta = table_metadata(df)
    classes = [str(c) for c in (meta.get("classes") or (side or {}).get("classes") or TERRAIN_CLASSES)]
    name, added = str(terrain).strip(), False
    if not name:
        raise ValueError(f"{path}: empty class name")
    if name.lstrip("-").isdigit():
        cid = int(name)
        if not 0 <= cid < len(classes):
            raise ValueError(f"{path}: class id {cid} is not in the run's classes {classes}; give a name to add one")
        name = classes[cid]
    elif name in classes:
        cid = classes.index(name)
    else:
        cid, classes, added = len(classes), [*classes, name], True
    df["terrain"] = np.full(len(df), cid, dtype=np.int64)
    meta["classes"] = classes
    if isinstance(meta.get("unknown_ground"), dict):
        meta["unknown_ground"] = {**meta["unknown_ground"], "label": name}
    write_run_parquet(df, out, metadata=meta)
    return Labelled(out, cid, name, classes, _label_sidecar(side, out, name, cid, classes), added)


def _read_sidecar(path: Path) -> dict | None:
    """The run's JSON sidecar ``path.with_suffix(".json")`` (None when there is none)."""
    side = path.with_suffix(".json")
    if not side.is_file():
        return None
    try:
        doc = json.loads(side.read_text())
    except (OSError, ValueError) as exc:
        raise ValueError(f"{side}: not a readable sidecar ({exc})") from None
    if not isinstance(doc, dict):
        raise ValueError(f"{side}: not a readable sidecar (not a JSON object)")
    return doc


def _not_parquet(path: Path, terrain: str, side: dict | None) -> str:
    """The refusal of a log that is not a Parquet run table, with the commands to run instead."""
    kind = "an MCAP log" if path.suffix.lower() == ".mcap" else f"a {path.suffix or 'suffix-less'} file"
    robot = shlex.quote(str((side or {}).get("robot") or "ROBOT"))
    src, run, terrain = (shlex.quote(str(x)) for x in (path, path.with_suffix(".parquet"), terrain))
    return (f"{kind}, not a Parquet run table: dataset label sets the terrain of a run table (an MCAP's "
            f"/terrain/label holds bare class ids, no class names). Ingest it to Parquet beside its sidecar "
            f"first, then label that: terrainml ingest {src} --robot {robot} --out {run} && "
            f"terrainml dataset label {run} --terrain {terrain}")


def _label_sidecar(doc: dict | None, out: Path, name: str, cid: int, classes: list) -> Path | None:
    """The run's JSON sidecar ``doc`` with its label, beside ``out`` (None when the run has none)."""
    if doc is None:
        return None
    doc = {**doc, "label": name, "label_id": cid, "run": out.name, "format": "parquet", "classes": classes}
    return write_text(out.with_suffix(".json"), json.dumps(doc, indent=2, sort_keys=True) + "\n")
