"""Sensor members of a model folder: the same training on the useful subsets of its sensor groups.

A model trained on every sensor group a robot has serves nothing when one group is missing at
serving (a robot without its IMU, a log without the currents, a tracking camera whose confidence
drops for a second on wet ground): its windows need that group's channels. So ``terrainml train``
(design §9) also trains, for each useful subset of the model's groups
(:func:`~terrainml.pipeline.sensor_subsets.member_subsets`: without the IMU, without the
currents, without the camera), a member:
a complete model folder of its own in ``members/NAME/``, made by the very training function
that made the folder's model (the caller's ``fit``, on data built for that subset), and listed in
the folder's manifest (:func:`terrainml.models.artifacts.attach_members`). The predictor serves
the best member whose groups are healthy (:mod:`terrainml.stream.tick.predictor`).
"""

from __future__ import annotations

import shutil
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable, Sequence

from joblib import Parallel, delayed, effective_n_jobs

from terrainml.models.artifacts import MEMBERS_DIR, attach_members, write_manifest
from terrainml.pipeline.dataset import Dataset, build_from_tables
from terrainml.pipeline.progress import report
from terrainml.pipeline.sensor_subsets import member_subsets, subset_dataset
from terrainml.pipeline.replay import ReplayRefused
from terrainml.pipeline.train import train

__all__ = ["member_jobs", "train_members", "reuses_windows", "fixed_fit"]


def member_jobs(n_jobs: int | None, n_members: int) -> tuple[int, int]:
    """(members trained at once, joblib jobs of each) for ``n_jobs`` (joblib's, -1: every core).

    A member's own training (grouped CV over a few folds, a final fit, a replay of a few folds)
    keeps only part of the cores busy: the last round of folds and the final fit run alone. So
    with several cores the members train side by side, and share out the cores among them.
    """
    cores = max(1, effective_n_jobs(n_jobs))
    at_once = max(1, min(n_members, cores))
    return at_once, max(1, cores // at_once)


def train_members(out: str | Path, sensors: Sequence[str], fit: Callable[[list[str], Path], Any],
                  progress: Callable[[str], None] | None = None, n_jobs: int = 1) -> list[str]:
    """Train the members of the model folder ``out`` and list them in its manifest.

    Parameters
    ----------
    out : the model folder (its model already saved, on ``sensors``).
    sensors : the model's sensor groups.
    fit : ``fit(subset, folder)`` trains and saves one model folder on the groups ``subset``
        with the caller's training (the same function and options that made the model).
        A ValueError (e.g. the subset's data gives no windows) skips that member, with a warning
        through ``progress``.
    progress : callback with a short message and a :class:`~terrainml.pipeline.progress.Step`
        (stage ``members``) per member.
    n_jobs : members trained at once (joblib worker processes; see :func:`member_jobs`). Above 1,
        ``fit`` is sent to the workers (it must pickle with cloudpickle: no console, no open
        file) and should use its share of the cores; the members and the manifest are the same
        as one at a time.

    Returns
    -------
    The names of the members saved (in :data:`~terrainml.pipeline.sensor_subsets.MEMBER_DROPS` order).
    """
    say = progress or (lambda msg: None)
    out = Path(out)
    subsets = member_subsets(sensors)
    folders = {name: out / MEMBERS_DIR / name for name in subsets}
    calls = [delayed(_fit_member)(fit, subset, folders[name]) for name, subset in subsets.items()]
    report(say, "members", 0, len(subsets), "members",
           f"{', '.join(subsets)}: training on {'; '.join(','.join(s) for s in subsets.values())}")
    names = []
    # max_nbytes=None: no memmapped arrays in the workers (a model holding one would be saved with
    # a numpy.memmap, a type loading refuses)
    done = Parallel(n_jobs=n_jobs, return_as="generator", max_nbytes=None)(calls) if calls else []
    for i, ((name, subset), why) in enumerate(zip(subsets.items(), done)):
        if why:
            shutil.rmtree(folders[name], ignore_errors=True)  # nothing half-written stays in the folder
            say(f"warning: member {name} ({','.join(subset)}) not trained: {why}")
        else:
            names.append(name)
        report(say, "members", i + 1, len(subsets), "members", name)
    if names:
        attach_members(out, names)
    else:
        write_manifest(out)  # nothing listed; the folder's file list stays exact
    return names


def _fit_member(fit: Callable[[list[str], Path], Any], subset: list[str], folder: Path) -> str:
    """Why ``fit`` did not train the member (its ValueError), or an empty text; runs in a joblib worker."""
    try:
        fit(subset, folder)
    except ValueError as exc:
        return str(exc) or type(exc).__name__
    return ""


def reuses_windows(ds: Dataset) -> bool:
    """Whether a member's windows are the model's with the member's channels
    (:func:`~terrainml.pipeline.sensor_subsets.subset_dataset`):
    when cutting them again would give the same windows, i.e. no window was rejected for an invalid
    channel (the only window rule that reads the channels) and the spec is not chunked (chunks span
    the runs that hold its columns)."""
    return ds.spec.chunk_s is None and not ds.counts.get("channel_valid", 0)


def fixed_fit(ds: Dataset, kinds: Sequence[str], options: Any, serve: Any = None,
              tables: Sequence[Any] | None = None,
              progress: Callable[[str], None] | None = None) -> Callable[[list[str], Path], None]:
    """The ``fit(subset, folder)`` of :func:`train_members` for a model that
    :func:`~terrainml.pipeline.train.train` made on ``ds`` with ``kinds``, ``options`` (its
    ``n_jobs``: each member's share) and ``serve``.

    A member's windows are the model's with its channels where cutting them again would give the
    same (:func:`reuses_windows`) or no run ``tables`` are given, else they are cut again from
    ``tables`` for the subset; with ``tables`` every member gets the served replay, and one that
    its replay refuses raises ValueError (so it is not saved).
    """
    exact = reuses_windows(ds)
    own = None if serve is None else replace(serve, members=False)  # a member has no members of its own

    def fit(subset: list[str], folder: Path) -> None:
        sub = (subset_dataset(ds, subset) if exact or tables is None else
               build_from_tables(tables, ds.robot, ds.preset, replace(ds.spec, channels=None),
                                 n_jobs=options.n_jobs, sensors=subset))
        try:
            train(sub, folder, kinds, options, own, tables=tables, progress=progress)
        except ReplayRefused as exc:
            raise ValueError(f"its served replay refuses it: {exc}") from None

    return fit
