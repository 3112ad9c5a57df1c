"""The served replay of fold models: each fold's held-out runs served by the model fitted without them.

``train`` proves a model on the served path before saving it (:mod:`terrainml.pipeline.replay`):
every fold's model is saved as a model folder, loaded as ``terrainml predict`` loads one, and
serves a course of the fold's held-out runs (:func:`replay_folds`). A folder that ``train`` saves
with sensor members (:mod:`terrainml.pipeline.members`) is served with them, so a fold's model
is replayed with the members its held-out runs call on (:class:`FoldMember`: for every group
those runs flag invalid, :func:`~terrainml.pipeline.sensor_subsets.flagged_groups`), each fitted
on the fold's training windows alone. The folds run side by side in joblib workers; a fold's
members are fitted in its worker.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from tempfile import TemporaryDirectory
from typing import Any, Callable, Sequence

import pandas as pd
from joblib import Parallel, delayed, effective_n_jobs

from terrainml.models.artifacts import MEMBERS_DIR, TABLE_FILE, TrainingProvenance, attach_members, save_artifact
from terrainml.models.calibration import Temperature
from terrainml.models.ensemble import ProbabilityAverage
from terrainml.models.novelty import DEFAULT_FALSE_ALARM, NoveltyError, fit_model_novelty
from terrainml.pipeline.progress import report
from terrainml.pipeline.replay import replay_course

__all__ = ["FoldModel", "FoldMember", "replay_folds", "served_novelty", "table_attachment"]


@dataclass
class FoldMember:
    """A sensor member of one fold's model, fitted in the fold's replay.

    Attributes
    ----------
    name : the member's name (``no_imu``, ...). factories : {model kind: factory of an unfitted
    model} of the fold's served model's kinds on the member's channels. served : the name served
    (``svm``, or ``svm+hgb``: the mean of both). windows : the fold's training windows on the
    member's channels. provenance : the member's, saved with it.
    """

    name: str
    factories: dict
    served: str
    windows: Any
    provenance: TrainingProvenance


@dataclass
class FoldModel:
    """One fold's model, to serve on the fold's held-out runs (:func:`replay_folds`).

    Attributes
    ----------
    runs : the held-out run ids. fitted : {name: fitted model} to save (an average's members too).
    served : the name served. train_windows : the fold's training windows (its novelty score).
    provenance : saved with the model (its classes are the fitted model's).
    temperature : of the served model's probabilities (1: uncalibrated). label : report label.
    members : the sensor members its held-out runs call on, fitted in its replay.
    course : the replayed pieces of its held-out runs end to end
    (:func:`~terrainml.pipeline.replay.make_course`), None when none of them has a table.
    replayed : the held-out runs in the course.
    """

    runs: list
    fitted: dict
    served: str
    train_windows: Any
    provenance: TrainingProvenance
    temperature: float = 1.0
    label: str = ""
    members: list = field(default_factory=list)
    course: pd.DataFrame | None = None
    replayed: list = field(default_factory=list)


def served_novelty(model: Any, name: str, W, seed: int, say: Callable[[str], None],
                   novelty_false_alarm: float = DEFAULT_FALSE_ALARM):
    """(name, scorer, info) of the served model's novelty score, or None (named) without one;
    ``novelty_false_alarm``: the threshold's target (:func:`~terrainml.models.novelty.fit_novelty`)."""
    say(f"{name}: novelty score (threshold at {100 * novelty_false_alarm:g} % of the training runs' moving "
        "windows, one run held out at a time)")
    try:
        scorer, info = fit_model_novelty(model, W, seed=seed, novelty_false_alarm=novelty_false_alarm)
    except NoveltyError as exc:
        say(f"{name}: no novelty score ({exc})")
        return None
    return name, scorer, info


def replay_folds(folds: Sequence[FoldModel], table: Any, seed: int, say: Callable[[str], None],
                 novelty_false_alarm: float = DEFAULT_FALSE_ALARM, n_jobs: int = 1) -> list[dict]:
    """Replay of every fold's held-out runs through its model and its novelty score (fitted on the
    fold's training windows only), saved and loaded as ``terrainml predict`` loads them.

    A fold model is saved with the classes it was fitted on (a class left out of the folds, e.g.
    one with a single run, is neither known to it nor among its held-out runs), and with its
    members (:class:`FoldMember`), fitted on the fold's training windows.
    ``n_jobs``: folds replayed at once (joblib; each fold's replay is one process's serial tick
    loop, so folds are the unit of parallel work); the notes of a fold are said when it is done.

    Returns
    -------
    list of dicts per fold, in fold order: ``fold``, ``chosen``, ``runs``, ``members`` (the
    members served with it) and :func:`~terrainml.pipeline.replay.replay_course`'s figures,
    ``replay_s``.
    """
    calls = [delayed(_replay_fold)(k, f, table, seed, novelty_false_alarm) for k, f in enumerate(folds)]
    at_once = max(1, min(len(folds), effective_n_jobs(n_jobs)))
    n_members = sum(len(f.members) for f in folds)
    report(say, "served replay", 0, len(folds), "folds",
           f"{len(folds)} folds' held-out runs through the online predictor, {at_once} at once"
           + (f", with {n_members} fold members to fit" if n_members else ""))
    out = []
    # max_nbytes=None: no memmapped arrays in the workers (a model holding one would be saved with
    # a numpy.memmap, a type loading refuses)
    for res, notes in Parallel(n_jobs=n_jobs, return_as="generator", max_nbytes=None)(calls):
        for note in notes:
            say(note)
        out.append(res)
        report(say, "served replay", len(out), len(folds), "folds",
               f"fold {res['fold'] + 1}: {res['runs']} held-out runs")
    return out


def _replay_fold(k: int, f: FoldModel, table: Any, seed: int,
                 novelty_false_alarm: float) -> tuple[dict, list[str]]:
    """(figures, notes) of one fold's replay (:func:`replay_folds`); runs in a joblib worker."""
    notes: list[str] = []
    if f.course is None:
        return {"fold": k, "runs": 0, "moving_ticks": 0, "chosen": f.label or f.served, "members": []}, notes
    novelty = served_novelty(f.fitted[f.served], f.served, f.train_windows, seed, notes.append, novelty_false_alarm)
    with TemporaryDirectory() as tmp:
        folder = Path(tmp) / "m"
        _save(folder, f.fitted, f.served, f.provenance, table, f.temperature, novelty)
        for m in f.members:
            notes.append(f"fold {k + 1}: member {m.name} for its held-out runs, fitted on {len(m.windows)} windows")
            _fit_member(folder / MEMBERS_DIR / m.name, m, table, seed, novelty_false_alarm, notes.append)
        if f.members:
            attach_members(folder, [m.name for m in f.members])
        t0 = time.perf_counter()
        res = replay_course(folder, f.course)
    return {"fold": k, "chosen": f.label or f.served, "runs": len(f.replayed), "members": [m.name for m in f.members],
            **res, "replay_s": time.perf_counter() - t0}, notes


def _fit_member(folder: Path, m: FoldMember, table: Any, seed: int, novelty_false_alarm: float,
                say: Callable[[str], None]) -> None:
    """Fit one fold member on its windows and save it (with its novelty score) in ``folder``."""
    W = m.windows
    fitted = {}
    for kind, factory in m.factories.items():
        fitted[kind] = factory()
        fitted[kind].fit(W, W.y, groups=W.groups)
    if m.served not in fitted:
        fitted[m.served] = ProbabilityAverage.from_fitted([fitted[q] for q in m.served.split("+")])
    novelty = served_novelty(fitted[m.served], m.served, W, seed, lambda msg: say(f"member {m.name}, {msg}"),
                             novelty_false_alarm)
    _save(folder, fitted, m.served, m.provenance, table, 1.0, novelty)


def _save(folder: Path, fitted: dict, served: str, provenance: TrainingProvenance, table: Any,
          temperature: float, novelty: Any) -> None:
    """A fold model (or member) saved as ``predict`` loads a model folder."""
    save_artifact(folder, fitted, provenance, default_model=served,
                  attachments=table_attachment(table), calibration={served: Temperature(temperature).to_dict()},
                  novelty=novelty)


def table_attachment(table: Any) -> dict[str, str] | None:
    """The attachments of a model folder served with the desired-slip ``table`` (None: none)."""
    return None if table is None else {TABLE_FILE: table.to_json() + "\n"}
