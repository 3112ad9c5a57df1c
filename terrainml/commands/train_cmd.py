"""``terrainml train``: its options resolved once into frozen records, then the selecting or the
single-spec training, the sensor members and the console summary.

Exit codes: 0 on success, 2 when the data is unusable or the served replay refuses the model
(message names the file); never a traceback. Outputs and ``--n-jobs`` are checked before any
long work.
"""

from __future__ import annotations

import json
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Iterator, Optional

import typer
from rich.table import Table

from terrainml.commands._help import robot_help
from terrainml.pipeline.train_options import DEFAULT_BUDGET_MIN, REPLAY_SEGMENT_S
from terrainml.commands._common import (check_n_jobs, check_output_writable, console, fail, failure_message,
                                        is_windows_file, open_dataset)
from terrainml.commands._model_inputs import (NOVELTY_FALSE_ALARM_HELP, check_novelty_false_alarm_option,
                                              check_sensors, load_data, load_tables)
from terrainml.models.novelty_target import DEFAULT_FALSE_ALARM

if TYPE_CHECKING:  # the pipeline imports numpy and pandas: not at ``--help``
    from terrainml.features.windows import WindowSpec
    from terrainml.pipeline.train_options import SelectionOptions, ReplayOptions, TrainOptions


@dataclass(frozen=True)
class DataSource:
    """Where ``train`` reads its runs and how it cuts them.

    Attributes
    ----------
    data : windows Parquet or folder of logs. robot : robot spec name or path (None: default).
    preset : estimation preset. fmt : ``auto`` or ``borealtc``.
    sensors : sensor groups the model may use (None: all). dask_address : Dask scheduler or None.
    """

    data: Path
    robot: Optional[str]
    preset: str
    fmt: str
    sensors: Optional[tuple[str, ...]]
    dask_address: Optional[str]


@dataclass(frozen=True)
class TrainRequest:
    """``train``'s options, resolved once at the command line.

    Attributes
    ----------
    source : :class:`DataSource`. out : folder written (the staging folder); shown : the folder
        as the user named it (messages).
    kinds : model names of the single-spec path (None: selecting). spec : its window spec.
    selection : :class:`~terrainml.pipeline.train_options.SelectionOptions` of the selecting path (None:
        single-spec). options, serve : :class:`~terrainml.pipeline.train_options.TrainOptions`,
        :class:`~terrainml.pipeline.train_options.ReplayOptions`.
    members : also train the sensor members. quiet : print errors only.
    """

    source: DataSource
    out: Path
    shown: Path
    kinds: Optional[tuple[str, ...]]
    spec: Optional[WindowSpec]
    selection: Optional[SelectionOptions]
    options: TrainOptions
    serve: ReplayOptions
    members: bool
    quiet: bool


def _check_numbers(folds: int, budget_min: float, replay_s: float, novelty_false_alarm: float,
                   n_jobs: int) -> None:
    """Exit 2 naming the option whose number ``train`` cannot use."""
    if folds < 2:
        fail("--folds must be >= 2")
    if not budget_min > 0:
        fail("--budget-min must be > 0")
    if not replay_s > 0:
        fail("--replay-s must be > 0")
    check_novelty_false_alarm_option(novelty_false_alarm)
    check_n_jobs(n_jobs)


def train(
    data: Path = typer.Option(..., "--data", "-d", help="Windows Parquet (from 'dataset build') or a folder "
                              "of logs (the dataset is built first)."),
    out: Path = typer.Option(..., "--out", "-o", help="Model folder to create, e.g. runs/NAME."),
    model: str = typer.Option("auto", "--model", "-m", help="auto (default: svm, hgb and svm+hgb, chosen under "
                              "nested run-grouped CV; auto,cnn adds the CNN), or svm, cnn, hgb, all (svm and "
                              "cnn), an average such as svm+hgb, or several comma-separated (trains them all). "
                              "A model named alone keeps --windows auto (the window spec is still chosen for "
                              "it); name both the model and the windows for no selection at all."),
    windows: str = typer.Option("auto", "--windows", help="Window spec when --data is a folder: auto (default: "
                                "short, chunks, state and steady where the data feeds them, chosen with the "
                                "model), several comma-separated to choose among, or short, steady, "
                                "chunks (BorealTC authors' windows), state. One spec with a named --model: "
                                "that model on those windows, grouped CV and served replay, no selection."),
    budget_min: float = typer.Option(DEFAULT_BUDGET_MIN, "--budget-min",
                                     help="Time budget of the selection, minutes: past half of it after "
                                     "screening, only the best window spec gets its models."),
    replay_s: float = typer.Option(REPLAY_SEGMENT_S, "--replay-s",
                                   help="Seconds of every held-out run replayed through the online "
                                   "predictor before the model is saved."),
    allow_unproven: bool = typer.Option(False, "--allow-unproven", help="Save the selected model even when the "
                                        "served replay of held-out runs classifies on too few moving ticks."),
    sensors: Optional[str] = typer.Option(None, "--sensors", help="Sensor groups the model may use, e.g. "
                                          "wheels,currents (of wheels, currents, imu, cam; default all). "
                                          "The served model checks health only on these. Without cam on a "
                                          "robot with a camera, the EKF's body velocity (vx, vy, r) is left "
                                          "out too: the camera is its reference."),
    folds: int = typer.Option(5, "--folds", help="Outer grouped CV folds (by run)."),
    seed: int = typer.Option(0, "--seed", help="Seed of folds and models."),
    n_jobs: int = typer.Option(-1, "--n-jobs", "-j", envvar="TERRAINML_N_JOBS",
                               help="Parallel jobs (fits; logs when building); -1: every core."),
    dask_address: Optional[str] = typer.Option(None, "--dask-address", help="Dask scheduler "
                                               "(tcp://HOST:PORT): the fits (and the dataset build from "
                                               "logs) run on its cluster, whose threads set the "
                                               "parallelism; same figures as without it."),
    preset: str = typer.Option("robust", "--preset", help="Estimation preset when building from logs."),
    robot: Optional[str] = typer.Option(None, "--robot", help="When building from logs: " + robot_help(
        "the dataset format's robot (husky for borealtc), else the reference robot")),
    fmt: str = typer.Option("auto", "--format", help="auto or borealtc (when --data is a folder)."),
    ablation: bool = typer.Option(False, "--ablation/--no-ablation", help="With --model svm and one window spec, "
                                  "also the SVM feature-set ablation: kinematic, currents, imu and all on the same "
                                  "folds (report.md, ablation.csv; 12 more fits). The members already give the "
                                  "figure without IMU and without currents."),
    members: bool = typer.Option(True, "--members/--no-members", help="Also train, the same way, members "
                                 "for the sensor subsets without IMU, without currents and without the camera "
                                 "(members/NAME in the folder); serving uses the best one whose sensors are "
                                 "healthy, e.g. the one without camera while a tracking camera's confidence "
                                 "is low. The served replay serves each fold's held-out runs the same way, "
                                 "with the members they call on fitted on the fold's training runs."),
    open_set: bool = typer.Option(False, "--open-set", help="Also evaluate unknown-ground detection: each class "
                                  "in turn held out of training and scored as the unknown by the served "
                                  "model's novelty (one more CV per class; report.md section, as "
                                  "'terrainml evaluate --open-set')."),
    novelty_false_alarm: float = typer.Option(DEFAULT_FALSE_ALARM, "--novelty-false-alarm",
                                              help=NOVELTY_FALSE_ALARM_HELP),
    catalogue: Optional[str] = typer.Option(None, "--catalogue", help="Terrain catalogue with the parameters of "
                                            "the data's classes (YAML path or built-in: reference, borealtc): "
                                            "the model serves their desired slip from it. Default: the built-in "
                                            "one with every class; with none, every class is served the "
                                            "class-free safe cap (report and served messages say so)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print errors only."),
) -> None:
    """Cross-validate (grouped by run), train, report and save a terrain classifier.

    By default (--windows auto --model auto) the window spec and the model are chosen on the
    data under nested run-grouped CV, the held-out runs of every outer fold are replayed through
    the online predictor, and the calibrated model is saved (report.md shows every candidate).
    With the model and one window spec named, that model is fitted on those windows under grouped
    CV and the same served replay, with no selection. The data checks that can refuse run first
    (runs per class, class names against the catalogue, sensors); the folder appears at --out
    only once complete (members included).

    Example: terrainml train --data ../shared/datasets/borealtc --format borealtc --out runs/boreal

    Example: terrainml train --data data/windows.parquet --model svm --folds 5 --seed 0 --out runs/svm

    Example (from logs, both models): terrainml train --data data/sim --model all --out runs/all
    """
    selecting, kinds, specs = _train_mode(data, model, windows)
    _check_numbers(folds, budget_min, replay_s, novelty_false_alarm, n_jobs)
    check_output_writable(out, folder=True)
    from terrainml.commands.dataset_cmds import parse_sensors
    from terrainml.pipeline.train_options import SelectionOptions, ReplayOptions, TrainOptions

    groups = parse_sensors(sensors)
    groups = None if groups is None else tuple(groups)
    req = TrainRequest(
        source=DataSource(data, robot, preset, fmt, groups, dask_address), out=out, shown=out,
        kinds=None if selecting else tuple(kinds), spec=None if selecting else specs[0],
        selection=SelectionOptions(specs=tuple(specs), models=tuple(kinds), budget_min=budget_min, preset=preset,
                                   sensors=groups) if selecting else None,
        options=TrainOptions(folds=folds, seed=seed, n_jobs=n_jobs, novelty_false_alarm=novelty_false_alarm,
                             ablation=ablation, open_set=open_set),
        serve=ReplayOptions(segment_s=replay_s, allow_unproven=allow_unproven, catalogue=catalogue,
                            members=members and groups is None),
        members=members, quiet=quiet)
    _run(req)


def _run(req: TrainRequest) -> None:
    """The training of ``req`` into a staging folder published at ``req.shown`` once complete; a
    model the served replay refuses leaves its report beside it (``NAME.refused``)."""
    if not req.quiet:  # before the pipelines' imports (seconds), so the command answers at once
        console.print(_first_line(req), highlight=False)
    from terrainml.atomic import publish_folder, staged_folder
    from terrainml.pipeline.replay import ReplayRefused

    data, out = req.source.data, req.shown
    try:
        with staged_folder(out) as stage:  # --out appears whole (members included) or not at all
            try:
                (_train_auto if req.selection is not None else _train_fixed)(replace(req, out=stage))
            except ReplayRefused as exc:  # no model: its report goes beside --out, an older --out is kept
                refused = publish_folder(exc.report_dir or stage, out.with_name(f"{out.name}.refused"))
                fail(f"{data}: refused: {exc} (report: {refused / 'report.md'})")
    except OSError as exc:
        fail(failure_message(data, exc, out))


def _first_line(req: TrainRequest) -> str:
    """What ``train`` will do and its time budget (the selection's; the fixed path has none)."""
    folds = req.options.folds
    if req.selection is None:
        return (f"train: {', '.join(req.kinds)} under grouped {folds}-fold CV by run, the served replay of every "
                "fold's held-out runs, then fitted on every window; no selection, so no time budget "
                "(--budget-min is the selection's)")
    choice = req.selection
    return (f"train: choosing the window spec ({','.join(s.name for s in choice.specs)}) and the model "
            f"({','.join(choice.models)}) under nested run-grouped {folds}-fold CV; time budget "
            f"{choice.budget_min:g} min (--budget-min): when screening the window specs takes more than half of "
            "it, only the best spec gets its models (the budget does not stop the run: every kept candidate is "
            "still scored)")


def _train_mode(data: Path, model: str, windows: str) -> tuple[bool, list, list]:
    """(selecting?, model names, parsed window specs) of ``train``'s options; exits 2 on a bad one.

    ``--model auto`` or several or ``auto`` window specs (of a folder: a windows file has its
    spec already) select under nested CV among the candidates; otherwise the single-spec path
    (one model list, one spec).
    """
    from terrainml.features.windows import window_spec
    from terrainml.pipeline.candidates import candidate_window_specs, parse_auto_models, parse_models

    selecting = "auto" in [m.strip() for m in model.split(",")] or (
        (windows == "auto" or "," in windows) and not is_windows_file(data))
    try:
        if selecting:
            return True, parse_auto_models(model), candidate_window_specs(windows)
        return False, parse_models(model), [window_spec("short" if windows == "auto" else windows)]
    except ValueError as exc:
        fail(f"--model/--windows: {exc}")


def _warn(quiet: bool):
    """The preflight checks' warning printer (None when quiet)."""
    return None if quiet else (lambda msg: console.print(f"[yellow]warning:[/]{msg[len('warning:'):]}",
                                                         highlight=False))


@contextmanager
def _fits_on(dask_address: Optional[str], quiet: bool) -> Iterator[None]:
    """The fits inside run on the Dask cluster at ``dask_address`` (None: here); exits 2 naming the
    option when the scheduler cannot be reached."""
    from terrainml.pipeline.cluster import ClusterError, cluster_summary, dask_jobs, worker_env_note

    try:
        with dask_jobs(dask_address) as client:
            if client is not None and not quiet:
                console.print(f"train: fits run on the Dask cluster at {dask_address} ({cluster_summary(client)})",
                              highlight=False)
                note = worker_env_note(client)
                if note:
                    console.print(f"[cyan]note:[/]{note[len('note:'):]}", highlight=False)
            yield
    except ClusterError as exc:  # only the connection raises it
        fail(f"--dask-address: {exc}")


# ------------------------------------------------------------------------------ single spec
def _train_fixed(req: TrainRequest) -> None:
    """``train`` with the model kinds and window spec given (no selection): grouped CV, the served
    replay of every fold's held-out runs, final fit; ``req.out`` is written, ``req.shown`` named."""
    from terrainml.commands._progress import StageReporter
    from terrainml.pipeline.replay import ReplayRefused
    from terrainml.pipeline.train import train as do_train

    src, opt, out = req.source, req.options, req.out
    try:
        with StageReporter(console, quiet=req.quiet) as say:
            tables, ds, pre = _fixed_data(req, say)
            with _fits_on(src.dask_address, req.quiet):
                res = do_train(ds, out, req.kinds, opt, req.serve, tables=tables, preflight=pre.doc(), progress=say)
                names = []
                if req.members and src.sensors is None:
                    names = _train_members(req, ds, tables, say)
    except (typer.Exit, ReplayRefused):
        raise
    except Exception as exc:  # noqa: BLE001 - a message, never a traceback; the folder as the user named it
        fail(failure_message(src.data, exc, req.shown).replace(str(out), str(req.shown)))
    if not req.quiet:
        _print_fixed(res, req.shown)
        _print_members(out, names, req.shown)


def _fixed_data(req: TrainRequest, say):
    """(run tables or None, Dataset, Preflight) of the single-spec path: the checks that can refuse
    run on the runs' labels and names before the windows are cut (once, with every sensor group
    asked); ``say``: the stages ``logs`` and ``windows``."""
    from terrainml.pipeline.preflight import check_dataset, check_tables
    from terrainml.pipeline.progress import report

    src, quiet, catalogue = req.source, req.quiet, req.serve.catalogue
    groups = None if src.sensors is None else list(src.sensors)
    if is_windows_file(src.data):
        ds = open_dataset(src.data)
        if groups is not None:
            check_sensors(ds, groups)
        return None, ds, check_dataset(ds, catalogue=catalogue, say=_warn(quiet))
    tables, rb = load_tables(src.data, robot=src.robot, fmt=src.fmt, quiet=quiet, progress=say,
                             n_jobs=req.options.n_jobs)
    if not tables:
        fail(f"{src.data}: no usable run")
    pre = check_tables(tables, rb, catalogue=catalogue, specs=[req.spec], sensors=groups, say=_warn(quiet))
    report(say, "windows", 0, 1, "specs", f"cutting {len(tables)} runs with the {req.spec.name!r} spec")
    if src.dask_address is not None:  # the build on the cluster, from the logs
        ds = load_data(src.data, robot=src.robot, preset=src.preset, n_jobs=req.options.n_jobs,
                       dask_address=src.dask_address, fmt=src.fmt, quiet=True, spec=req.spec, sensors=groups)
    else:
        from terrainml.pipeline.dataset import build_from_tables

        ds = build_from_tables(tables, rb, src.preset, req.spec, n_jobs=req.options.n_jobs, sensors=groups)
    report(say, "windows", 1, 1, "specs", f"{len(ds.windows)} windows")
    if not quiet:
        from terrainml.commands.dataset_cmds import print_class_report, rejection_table

        console.print(rejection_table(ds))
        print_class_report(ds)
    return tables, ds, pre


def _member_jobs(req: TrainRequest, sensors) -> tuple[int, int]:
    """(members trained at once, jobs of each): side by side on this machine
    (:func:`~terrainml.pipeline.members.member_jobs`); one at a time with ``--dask-address``,
    their fits on the cluster."""
    from terrainml.pipeline.members import member_jobs
    from terrainml.pipeline.sensor_subsets import member_subsets

    if req.source.dask_address is not None:
        return 1, req.options.n_jobs
    return member_jobs(req.options.n_jobs, len(member_subsets(sensors)))


def _train_members(req: TrainRequest, ds, tables, say) -> list[str]:
    """The folder's sensor members, each trained like its model (grouped CV, served replay;
    :func:`~terrainml.pipeline.members.fixed_fit`)."""
    from terrainml.pipeline.members import fixed_fit, train_members

    at_once, jobs = _member_jobs(req, ds.sensors)
    options = replace(req.options, ablation=False, open_set=False, n_jobs=jobs)
    inner = say.nested() if at_once == 1 else None  # a worker process has no console
    return train_members(req.out, ds.sensors, fixed_fit(ds, req.kinds, options, req.serve, tables, inner),
                         progress=say, n_jobs=at_once)


def _print_fixed(res, shown: Path) -> None:
    """The console summary of the single-spec path: CV per model, served replay, folder."""
    t = Table(title=f"grouped {res.n_folds}-fold CV ({res.dataset_summary['n_runs']} runs, "
                    f"{res.dataset_summary['n_windows']} windows)", title_justify="left")
    t.add_column("model")
    for c in ("balanced acc.", "macro-F1", "desired-slip err.", "p50 ms/window"):
        t.add_column(c, justify="right")
    for k, r in res.models.items():
        s = r["cv"].summary
        dse = s.get("desired_slip_error_mean")
        t.add_row(k, f"{s['balanced_accuracy']['mean']:.3f} ± {s['balanced_accuracy']['std']:.3f}",
                  f"{s['macro_f1']['mean']:.3f} ± {s['macro_f1']['std']:.3f}",
                  "n/a" if not dse else f"{dse['mean']:.4f}", f"{r['latency']['p50_ms']:.2f}")
    console.print(t)
    pooled = (res.replay or {}).get("pooled") or {}
    if pooled.get("moving_ticks"):
        console.print(f"served replay of held-out runs: {100 * pooled['right_share']:.1f}% of "
                      f"{pooled['moving_ticks']} moving ticks right, {100 * pooled['fallback_share']:.1f}% "
                      "fallback" + (f" ([yellow]{res.replay['refusal']}[/], saved anyway: --allow-unproven)"
                                    if res.replay.get("refusal") else ""), highlight=False)
    console.print(f"[green]wrote[/] {shown} (served model: {res.default_model}; report {shown / 'report.md'})",
                  highlight=False)


def _print_members(out: Path, names, shown: Path | None = None) -> None:
    if not names:
        return
    doc = json.loads((out / "manifest.json").read_text())
    for m in doc.get("sensor_members", []):
        bacc = m.get("balanced_accuracy")
        console.print(f"member {m['name']}: sensors {','.join(m['sensors'] or [])}, served model "
                      f"{m['default_model']}, grouped CV balanced accuracy "
                      f"{'n/a' if bacc is None else f'{bacc:.3f}'} ({(shown or out) / m['path'] / 'report.md'})",
                      highlight=False)


# ------------------------------------------------------------------------------ selecting
def _train_auto(req: TrainRequest) -> None:
    """``train`` selecting the window spec and the model (``--windows auto`` / ``--model auto``);
    ``req.out`` is written, ``req.shown`` named."""
    from terrainml.commands._progress import StageReporter
    from terrainml.pipeline import autotrain
    from terrainml.pipeline.autotrain import ReplayRefused
    from terrainml.pipeline.preflight import check_dataset, check_tables

    src, choice, opt, out, quiet = req.source, req.selection, req.options, req.out, req.quiet
    catalogue, groups = req.serve.catalogue, None if src.sensors is None else list(src.sensors)
    try:
        with StageReporter(console, quiet=quiet) as say:
            if is_windows_file(src.data):
                ds = open_dataset(src.data)
                tables, rb, datasets = None, ds.robot, {ds.spec.name: ds}
                pre = check_dataset(ds, catalogue=catalogue, say=_warn(quiet))
            else:
                tables, rb = load_tables(src.data, robot=src.robot, fmt=src.fmt, quiet=quiet, progress=say,
                                         n_jobs=opt.n_jobs)
                datasets = None
                if not tables:
                    fail(f"{src.data}: no usable run")
                pre = check_tables(tables, rb, catalogue=catalogue, specs=list(choice.specs), sensors=groups,
                                   say=_warn(quiet))
            with _fits_on(src.dask_address, quiet):
                res = autotrain.train_auto(tables, rb, out, opt, choice, req.serve, datasets=datasets,
                                           progress=say, preflight=pre.doc())
                names = []
                if req.members and src.sensors is None and tables is not None:
                    names = _auto_members(req, res, tables, rb, say)
    except (typer.Exit, ReplayRefused):
        raise
    except Exception as exc:  # noqa: BLE001 - a message, never a traceback; the folder as the user named it
        fail(f"{src.data}: {type(exc).__name__}: {exc}".replace(str(out), str(req.shown)))
    if not quiet:
        _print_selection(res, req.shown)
        _print_members(out, names, req.shown)


def _auto_members(req: TrainRequest, res, tables, rb, say) -> list[str]:
    """The sensor members of a selected model: the chosen window spec and model trained again on
    each subset of its sensor groups. The choice is fixed, so a member gets one grouped CV (no
    nested selection) and reuses the model's windows and run groups (their channels of the subset:
    :func:`~terrainml.pipeline.sensor_subsets.subset_dataset`) where cutting them again would give the
    same windows (:func:`~terrainml.pipeline.members.reuses_windows`), else cuts its own; then the
    served replay of every fold's held-out runs and the final fit; a member whose replay refuses
    it is not saved (the folder then serves without it)."""
    from terrainml.pipeline.autotrain import ReplayRefused, train_auto
    from terrainml.pipeline.members import reuses_windows, train_members
    from terrainml.pipeline.sensor_subsets import subset_dataset

    chosen, ds = res.selection.chosen, res.dataset
    exact = reuses_windows(ds)
    spec = next(s for s in req.selection.specs if s.name == chosen.spec)
    sensors = res.train.dataset_summary["sensors"]
    at_once, jobs = _member_jobs(req, sensors)
    options = replace(req.options, open_set=False, n_jobs=jobs)
    serve = replace(req.serve, allow_unproven=False, members=False)  # a member has no members of its own
    inner = say.nested() if at_once == 1 else None  # a worker process has no console

    def fit(subset, folder):
        choice = replace(req.selection, specs=(spec,), models=(chosen.model,), budget_min=None, nested=False,
                         sensors=tuple(subset))
        try:
            train_auto(tables, rb, folder, options, choice, serve, progress=inner,
                       datasets={chosen.spec: subset_dataset(ds, subset)} if exact else None)
        except ReplayRefused as exc:
            raise ValueError(f"its served replay refuses it: {exc}") from None

    return train_members(req.out, sensors, fit, progress=say, n_jobs=at_once)


def _print_selection(res, out: Path) -> None:
    """The console summary of the selecting path: candidates, the choice, served replay, folder."""
    sel = res.selection
    t = Table(title=f"candidates: grouped {len(sel.partition)}-fold CV by run", title_justify="left")
    for c in ("candidate", "balanced acc.", "chosen in outer folds"):
        t.add_column(c, justify="left" if c == "candidate" else "right")
    for c in sel.candidates:
        cv = sel.cv.get(c.name)
        t.add_row(c.name + (" *" if c == sel.chosen else ""),
                  "screened out" if cv is None else f"{cv.summary['balanced_accuracy']['mean']:.3f}",
                  str(sum(o["chosen"] == c.name for o in sel.outer)))
    console.print(t)
    pooled = res.replay_pooled or {}
    replay = (f"; served replay of held-out runs: {100 * pooled['right_share']:.1f}% of "
              f"{pooled['moving_ticks']} moving ticks right, {100 * pooled['fallback_share']:.1f}% fallback"
              if pooled.get("moving_ticks") else "; served replay: not run")
    console.print(f"chosen [bold]{sel.chosen.name}[/]; nested run-grouped balanced accuracy (honest) "
                  f"{sel.honest['mean']:.3f} ± {sel.honest['std']:.3f} over folds, {sel.honest['pooled']:.3f} pooled"
                  f"{replay}; temperature {sel.temperature:.2f}",
                  highlight=False)
    if res.refusal:
        console.print(f"[yellow]warning:[/] {res.refusal} (saved anyway: --allow-unproven)", highlight=False)
    console.print(f"[green]wrote[/] {out} (served model: {sel.chosen.name}; report {out / 'report.md'})",
                  highlight=False)
