"""CLI commands of the models area: ``terrainml train``, ``terrainml evaluate`` and
``terrainml model keygen|sign|verify`` (signed model folders, :mod:`terrainml.models.signing`).

Exit codes: 0 on success, 2 when the data or the model folder is unusable (message names the
file); never a traceback. Outputs and ``--n-jobs`` are checked before any long work.
"""

from __future__ import annotations

import json
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator, List, Optional

import typer
from rich.table import Table

from terrainml.atomic import write_text
from terrainml.commands._common import (check_n_jobs, check_output_writable, console, fail, failure_message,
                                        is_windows_file, open_dataset)
from terrainml.models.novelty_target import DEFAULT_FALSE_ALARM, check_false_alarm

model_app = typer.Typer(help="Sign model folders and check their signatures (ed25519).", no_args_is_help=True)

_TRUSTED_KEY_HELP = ("Public key (KEY.pub from `terrainml model keygen`); the model folder must be signed by "
                     "it (`terrainml model sign`), else it is refused. Repeat for several.")
_NOVELTY_FALSE_ALARM_HELP = ("Target share of moving windows on known ground over the novelty threshold (held-out "
                             "training runs): higher finds more unknown ground and serves more known ground the "
                             "safe cap (`unknown_terrain`). In (0, 0.5).")


def _check_false_alarm_option(value: float) -> None:
    """The option checked by the novelty module's own rule (one definition of the range)."""
    try:
        check_false_alarm(value)
    except ValueError:
        fail(f"--novelty-false-alarm must be in (0, 0.5), e.g. 0.05, got {value}")


def _load_data(data: Path, *, robot, preset: str, n_jobs: int, dask_address, fmt: str, spec=None,
               quiet: bool = False, sensors=None):
    """A Dataset from a windows Parquet or (built first) a folder of logs."""
    if is_windows_file(data):
        return open_dataset(data)
    from terrainml.commands.dataset_cmds import build_with_progress, print_class_report, rejection_table

    ds = build_with_progress(data, robot=robot, preset=preset, n_jobs=n_jobs, dask_address=dask_address,
                             fmt=fmt, quiet=quiet, spec=spec, sensors=sensors)
    if not quiet:
        console.print(rejection_table(ds))
        print_class_report(ds)
    return ds


def train(
    data: Path = typer.Option(..., "--data", "-d", help="Windows Parquet (from `dataset build`) or a folder "
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
    budget_min: float = typer.Option(30.0, "--budget-min", help="Time budget of the selection, minutes: past "
                                     "half of it after screening, only the best window spec gets its models."),
    replay_s: float = typer.Option(30.0, "--replay-s", help="Seconds of every held-out run replayed through the "
                                   "online predictor before the model is saved."),
    allow_unproven: bool = typer.Option(False, "--allow-unproven", help="Save the selected model even when the "
                                        "served replay of held-out runs classifies on too few moving ticks."),
    sensors: Optional[str] = typer.Option(None, "--sensors", help="Sensor groups the model may use, e.g. "
                                          "wheels,currents (of wheels, currents, imu, cam; default all). "
                                          "The served model checks health only on these."),
    folds: int = typer.Option(5, "--folds", help="Outer grouped CV folds (by run)."),
    seed: int = typer.Option(0, "--seed", help="Seed of folds and models."),
    n_jobs: int = typer.Option(1, "--n-jobs", "-j", help="Parallel jobs (folds; logs when building)."),
    dask_address: Optional[str] = typer.Option(None, "--dask-address", help="Dask scheduler "
                                               "(tcp://HOST:PORT): the fits (and the dataset build from "
                                               "logs) run on its cluster, whose threads set the "
                                               "parallelism; same figures as without it."),
    preset: str = typer.Option("robust", "--preset", help="Estimation preset when building from logs."),
    robot: Optional[str] = typer.Option(None, "--robot", help="Robot spec when building from logs."),
    fmt: str = typer.Option("auto", "--format", help="auto or borealtc (when --data is a folder)."),
    ablation: bool = typer.Option(True, "--ablation/--no-ablation", help="SVM feature-set ablation."),
    members: bool = typer.Option(True, "--members/--no-members", help="Also train, the same way, members "
                                 "for the sensor subsets without IMU and without currents (members/NAME in "
                                 "the folder); serving uses the best one whose sensors are healthy."),
    open_set: bool = typer.Option(False, "--open-set", help="Also evaluate unknown-ground detection: each class "
                                  "in turn held out of training and scored as the unknown by the served "
                                  "model's novelty (one more CV per class; report.md section, as "
                                  "`terrainml evaluate --open-set`)."),
    novelty_false_alarm: float = typer.Option(DEFAULT_FALSE_ALARM, "--novelty-false-alarm",
                                              help=_NOVELTY_FALSE_ALARM_HELP),
    catalogue: Optional[str] = typer.Option(None, "--catalogue", help="Terrain catalogue with the parameters of "
                                            "the data's classes (YAML path or built-in: reference, borealtc): "
                                            "the model serves their desired slip from it. Default: the built-in "
                                            "one with every class; with none, every class is served the "
                                            "class-free safe cap (report and served messages say so)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print errors only."),
) -> None:
    """Cross-validate (grouped by run), train, report and save a terrain classifier.

    By default (``--windows auto --model auto``) the window spec and the model are chosen on the
    data under nested run-grouped CV, the held-out runs of every outer fold are replayed through
    the online predictor, and the calibrated model is saved (``report.md`` shows every candidate).
    With the model and one window spec named, that model is fitted on those windows under grouped
    CV and the same served replay, with no selection. The data checks that can refuse run first
    (runs per class, class names against the catalogue, sensors); the folder appears at ``--out``
    only once complete (members included).

    Example: ``terrainml train --data ../shared/datasets/borealtc --format borealtc --out runs/boreal``

    Example: ``terrainml train --data data/windows.parquet --model svm --folds 5 --seed 0 --out runs/svm``

    Example (from logs, both models): ``terrainml train --data data/sim --model all --out runs/all``
    """
    auto, kinds, spec = _train_mode(data, model, windows)
    if folds < 2:
        fail("--folds must be >= 2")
    if not budget_min > 0:
        fail("--budget-min must be > 0")
    if not replay_s > 0:
        fail("--replay-s must be > 0")
    _check_false_alarm_option(novelty_false_alarm)
    check_n_jobs(n_jobs)
    check_output_writable(out, folder=True)
    from terrainml.atomic import publish_folder, staged_folder
    from terrainml.pipeline.replay import ReplayRefused

    try:
        with staged_folder(out) as stage:  # --out appears whole (members included) or not at all
            try:
                if auto:
                    _train_auto(data, stage, model=model, windows=windows, sensors=sensors, folds=folds, seed=seed,
                                n_jobs=n_jobs, preset=preset, robot=robot, fmt=fmt, budget_min=budget_min,
                                allow_unproven=allow_unproven, replay_s=replay_s, members=members,
                                open_set=open_set, false_alarm=novelty_false_alarm, quiet=quiet,
                                catalogue=catalogue, dask_address=dask_address, shown=out)
                else:
                    _train_fixed(data, stage, kinds, spec, sensors=sensors, folds=folds, seed=seed, n_jobs=n_jobs,
                                 dask_address=dask_address, preset=preset, robot=robot, fmt=fmt, ablation=ablation,
                                 members=members, open_set=open_set, false_alarm=novelty_false_alarm, quiet=quiet,
                                 catalogue=catalogue, replay_s=replay_s, allow_unproven=allow_unproven, shown=out)
            except ReplayRefused as exc:  # no model: its report goes beside --out, an older --out is kept
                refused = publish_folder(exc.report_dir or stage, out.with_name(f"{out.name}.refused"))
                fail(f"{data}: refused: {exc} (report: {refused / 'report.md'})")
    except OSError as exc:
        fail(failure_message(data, exc, out))


def _train_fixed(data: Path, out: Path, kinds, spec, *, sensors, folds: int, seed: int, n_jobs: int,
                 dask_address, preset: str, robot, fmt: str, ablation: bool, members: bool, open_set: bool,
                 false_alarm: float, quiet: bool, catalogue, replay_s: float, allow_unproven: bool,
                 shown: Path) -> None:
    """``train`` with the model kinds and window spec given (no selection): grouped CV, the served
    replay of every fold's held-out runs, final fit; ``out`` is written, ``shown`` named."""
    from terrainml.commands._progress import StageReporter
    from terrainml.commands.dataset_cmds import parse_sensors
    from terrainml.pipeline.replay import ReplayRefused
    from terrainml.pipeline.train import ServePlan
    from terrainml.pipeline.train import train as do_train

    if not quiet:
        console.print(f"train: {', '.join(kinds)} under grouped {folds}-fold CV by run, the served replay of every "
                      "fold's held-out runs, then fitted on every window; no selection, so no time budget "
                      "(--budget-min is the selection's)", highlight=False)
    groups = parse_sensors(sensors)
    try:
        tables, ds, pre = _fixed_data(data, spec, groups, robot=robot, preset=preset, n_jobs=n_jobs,
                                      dask_address=dask_address, fmt=fmt, catalogue=catalogue, quiet=quiet)
        plan = ServePlan(tables, segment_s=replay_s, allow_unproven=allow_unproven, catalogue=catalogue,
                         preflight=pre.doc())
        with StageReporter(console, quiet=quiet) as say, _fits_on(dask_address, quiet):
            res = do_train(ds, out, kinds, folds=folds, seed=seed, n_jobs=n_jobs, ablation=ablation,
                           progress=say, open_set=open_set, novelty_false_alarm=false_alarm, serve=plan)
            names = []
            if members and sensors is None:
                names = _train_members(out, ds, tables, kinds, folds=folds, seed=seed, n_jobs=n_jobs, say=say,
                                       false_alarm=false_alarm, plan=plan)
    except (typer.Exit, ReplayRefused):
        raise
    except Exception as exc:  # noqa: BLE001 - a message, never a traceback; the folder as the user named it
        fail(failure_message(data, exc, shown).replace(str(out), str(shown)))
    if not quiet:
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
        _print_members(out, names, shown)


@contextmanager
def _fits_on(dask_address: Optional[str], quiet: bool) -> Iterator[None]:
    """The fits inside run on the Dask cluster at ``dask_address`` (None: here); exits 2 naming the
    option when the scheduler cannot be reached."""
    from terrainml.pipeline.cluster import ClusterError, cluster_summary, dask_jobs

    try:
        with dask_jobs(dask_address) as client:
            if client is not None and not quiet:
                console.print(f"train: fits run on the Dask cluster at {dask_address} ({cluster_summary(client)})",
                              highlight=False)
            yield
    except ClusterError as exc:  # only the connection raises it
        fail(f"--dask-address: {exc}")


def _fixed_data(data: Path, spec, groups, *, robot, preset: str, n_jobs: int, dask_address, fmt: str, catalogue,
                quiet: bool):
    """(run tables or None, Dataset, Preflight) of the fixed path: the checks that can refuse run on
    the runs' labels and names before the windows are cut (once, with every sensor group asked)."""
    from terrainml.pipeline.preflight import check_dataset, check_tables

    warn = None if quiet else (lambda msg: console.print(f"[yellow]warning:[/]{msg[len('warning:'):]}",
                                                         highlight=False))
    if is_windows_file(data):
        ds = open_dataset(data)
        if groups is not None:
            _check_sensors(ds, groups)
        return None, ds, check_dataset(ds, catalogue=catalogue, say=warn)
    tables, rb = _load_tables(data, robot=robot, fmt=fmt, quiet=quiet)
    if not tables:
        fail(f"{data}: no usable run")
    pre = check_tables(tables, rb, catalogue=catalogue, specs=[spec], sensors=groups, say=warn)
    if dask_address is not None:  # the build on the cluster, from the logs
        ds = _load_data(data, robot=robot, preset=preset, n_jobs=n_jobs, dask_address=dask_address, fmt=fmt,
                        quiet=quiet, spec=spec, sensors=groups)
        return tables, ds, pre
    from contextlib import nullcontext

    from terrainml.commands.dataset_cmds import print_class_report, rejection_table
    from terrainml.pipeline.dataset import build_from_tables

    with console.status("[bold]windows[/] cutting the runs", spinner="dots") if not quiet else nullcontext():
        ds = build_from_tables(tables, rb, preset, spec, n_jobs=n_jobs, sensors=groups)
    if not quiet:
        console.print(rejection_table(ds))
        print_class_report(ds)
    return tables, ds, pre


def _train_members(out: Path, ds, tables, kinds, *, folds: int, seed: int, n_jobs: int, say, false_alarm: float,
                   plan) -> list[str]:
    """The folder's sensor members, each trained like its model (grouped CV, served replay).

    A member's windows are the model's with the member's channels (``subset_dataset``) when that
    is what cutting them again would give: no window was rejected for an invalid channel (the
    only window rule that reads the channels) and the spec is not chunked (chunks span the runs
    that hold its columns). Otherwise they are cut again from the run tables for the subset.
    """
    from dataclasses import replace

    from terrainml.pipeline.dataset import build_from_tables
    from terrainml.pipeline.members import subset_dataset, train_members
    from terrainml.pipeline.replay import ReplayRefused
    from terrainml.pipeline.train import train as do_train

    exact = ds.spec.chunk_s is None and not ds.counts.get("channel_valid", 0)

    def fit(subset, folder):
        sub = (subset_dataset(ds, subset) if exact or tables is None else
               build_from_tables(tables, ds.robot, ds.preset, replace(ds.spec, channels=None), n_jobs=n_jobs,
                                 sensors=subset))
        try:
            do_train(sub, folder, kinds, folds=folds, seed=seed, n_jobs=n_jobs, ablation=False, progress=say.nested(),
                     novelty_false_alarm=false_alarm, serve=replace(plan, preflight=None))
        except ReplayRefused as exc:
            raise ValueError(f"its served replay refuses it: {exc}") from None

    return train_members(out, ds.sensors, fit, progress=say)


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


def _train_mode(data: Path, model: str, windows: str):
    """(selecting?, model kinds, window spec) of ``train``'s options; exits 2 on a bad one.

    ``--model auto`` or several or ``auto`` window specs (of a folder: a windows file has its
    spec already) select under nested CV; otherwise the single-spec path.
    """
    from terrainml.commands.dataset_cmds import window_spec_from_options
    from terrainml.pipeline.select import candidate_specs, parse_auto_models
    from terrainml.pipeline.train import parse_models

    auto = "auto" in [m.strip() for m in model.split(",")] or (
        (windows == "auto" or "," in windows) and not is_windows_file(data))
    try:
        if auto:
            parse_auto_models(model)
            for name in candidate_specs(windows):
                window_spec_from_options(name)
            return True, None, None
        return False, parse_models(model), window_spec_from_options("short" if windows == "auto" else windows)
    except ValueError as exc:
        fail(f"--model/--windows: {exc}")


def _load_tables(data: Path, *, robot, fmt: str, quiet: bool, progress=None):
    """(ingested run tables, RobotSpec) of a folder of logs or a BorealTC folder; ``progress``
    gets the stage ``logs`` (per log; BorealTC: the folder at once)."""
    from terrainml.commands._common import open_robot
    from terrainml.pipeline.progress import report

    if fmt == "borealtc":
        from terrainml.pipeline.dataset import borealtc_tables

        rb = open_robot(robot or "husky")
        say = None if quiet else (lambda msg: console.print(msg, highlight=False))
        report(progress, "logs", 0, None, "", f"reading the BorealTC folder {data}")
        return borealtc_tables(data, rb, say), rb
    if fmt != "auto":
        fail(f"unknown --format {fmt!r}; expected auto or borealtc")
    from terrainml.io.ingest import load_run
    from terrainml.pipeline.dataset import find_logs

    rb = open_robot(robot)
    tables, bad = [], []
    logs = find_logs(data)
    for i, p in enumerate(logs):
        report(progress, "logs", i, len(logs), "logs", p.name)
        res = load_run(p, robot=rb)
        if res.report.usable and len(res.table):
            tables.append(res.table)
        else:
            bad.append(f"{p.name}: {'; '.join(res.report.errors) or 'no usable rows'}")
    report(progress, "logs", len(logs), len(logs), "logs")
    if bad:
        console.print(f"[yellow]warning:[/] {len(bad)} log(s) unusable, left out: {'; '.join(bad[:5])}"
                      + (" ..." if len(bad) > 5 else ""), highlight=False)
    return tables, rb


def _train_auto(data: Path, out: Path, *, model: str, windows: str, sensors, folds: int, seed: int, n_jobs: int,
                preset: str, robot, fmt: str, budget_min: float, allow_unproven: bool, replay_s: float,
                members: bool, open_set: bool, false_alarm: float, dask_address, quiet: bool, catalogue,
                shown: Path) -> None:
    """``train`` selecting the window spec and the model (``--windows auto`` / ``--model auto``);
    ``out`` is written, ``shown`` named."""
    from terrainml.commands._progress import StageReporter
    from terrainml.commands.dataset_cmds import parse_sensors
    from terrainml.pipeline.autotrain import ReplayRefused, train_auto
    from terrainml.pipeline.preflight import check_dataset, check_tables
    from terrainml.pipeline.select import candidate_specs

    if not quiet:
        console.print(f"train: choosing the window spec ({windows}) and the model ({model}) under nested "
                      f"run-grouped {folds}-fold CV; time budget {budget_min:g} min (--budget-min): when "
                      "screening the window specs takes more than half of it, only the best spec gets its models "
                      "(the budget does not stop the run: every kept candidate is still scored)", highlight=False)
    warn = None if quiet else (lambda msg: console.print(f"[yellow]warning:[/]{msg[len('warning:'):]}",
                                                         highlight=False))
    try:
        with StageReporter(console, quiet=quiet) as say:
            if is_windows_file(data):
                ds = open_dataset(data)
                tables, rb, datasets = None, ds.robot, {ds.spec.name: ds}
                pre = check_dataset(ds, catalogue=catalogue, say=warn)
            else:
                tables, rb = _load_tables(data, robot=robot, fmt=fmt, quiet=quiet, progress=say)
                datasets = None
                if not tables:
                    fail(f"{data}: no usable run")
                pre = check_tables(tables, rb, catalogue=catalogue, specs=candidate_specs(windows),
                                   sensors=parse_sensors(sensors), say=warn)
            with _fits_on(dask_address, quiet):
                res = train_auto(tables, rb, out, specs=windows, models=model, folds=folds, seed=seed,
                                 n_jobs=n_jobs, budget_min=budget_min, preset=preset,
                                 sensors=parse_sensors(sensors), allow_unproven=allow_unproven, segment_s=replay_s,
                                 datasets=datasets, open_set=open_set, novelty_false_alarm=false_alarm,
                                 progress=say, catalogue=catalogue, preflight=pre.doc())
                names = []
                if members and sensors is None and tables is not None:
                    names = _auto_members(out, res, tables, rb, folds=folds, seed=seed, n_jobs=n_jobs,
                                          preset=preset, replay_s=replay_s, say=say, false_alarm=false_alarm,
                                          catalogue=catalogue)
    except (typer.Exit, ReplayRefused):
        raise
    except Exception as exc:  # noqa: BLE001 - a message, never a traceback; the folder as the user named it
        fail(f"{data}: {type(exc).__name__}: {exc}".replace(str(out), str(shown)))
    if not quiet:
        _print_selection(res, shown)
        _print_members(out, names, shown)


def _auto_members(out: Path, res, tables, rb, *, folds: int, seed: int, n_jobs: int, preset: str,
                  replay_s: float, say, false_alarm: float, catalogue=None) -> list[str]:
    """The sensor members of a selected model: the chosen window spec and model trained again on
    each subset of its sensor groups. The choice is fixed, so a member gets one grouped CV (no
    nested selection) and reuses the model's windows and run groups (their channels of the subset:
    :func:`~terrainml.pipeline.members.subset_dataset`) where cutting them again would give the
    same windows (the rule of :func:`_train_members`), else cuts its own; then the served replay of every fold's
    held-out runs and the final fit; a member whose replay refuses it is not saved (the folder
    then serves without it)."""
    from terrainml.pipeline.autotrain import ReplayRefused, train_auto
    from terrainml.pipeline.members import subset_dataset, train_members

    chosen = res.selection.chosen
    ds = res.dataset
    exact = ds.spec.chunk_s is None and not ds.counts.get("channel_valid", 0)  # as _train_members

    def fit(subset, folder):
        try:
            train_auto(tables, rb, folder, models=[chosen.model], folds=folds, seed=seed, n_jobs=n_jobs,
                       budget_min=None, preset=preset, sensors=subset, segment_s=replay_s, nested=False,
                       **({"datasets": {chosen.spec: subset_dataset(ds, subset)}} if exact else
                          {"specs": [chosen.spec]}),
                       novelty_false_alarm=false_alarm, progress=say.nested(), catalogue=catalogue)
        except ReplayRefused as exc:
            raise ValueError(f"its served replay refuses it: {exc}") from None

    return train_members(out, res.train.dataset_summary["sensors"], fit, progress=say)


def _print_selection(res, out: Path) -> None:
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


def _check_sensors(ds, sensors) -> None:
    """A windows file already has its channels: refuse ``--sensors`` that it does not match."""
    extra = [g for g in ds.sensors if g not in sensors]
    if extra:
        fail(f"the windows use sensor groups {ds.sensors}, not only {sensors}; rebuild them with "
             f"`terrainml dataset build ... --sensors {','.join(sensors)}`")


def evaluate(
    model_dir: Optional[Path] = typer.Argument(None, help="Model folder written by `terrainml train` (with "
                                               "--open-set optional: its window spec, robot, preset and "
                                               "served model kind are used, retrained in every fold)."),
    data: Path = typer.Option(..., "--data", "-d", help="Windows Parquet or folder of logs to score on."),
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="Write the metrics JSON here "
                                       "(stdout when omitted). With --open-set: a folder, gets open_set.md "
                                       "and open_set.json."),
    model: Optional[str] = typer.Option(None, "--model", "-m", help="Model in the folder (default: the served "
                                        "one). With --open-set and no folder: the model kind, svm (default), "
                                        "hgb or an average such as svm+hgb (not cnn: no feature space)."),
    open_set: bool = typer.Option(False, "--open-set", help="Leave-one-class-out: each class in turn is held "
                                  "out of training (grouped CV by run) and plays the unknown ground; prints "
                                  "per held-out class the novelty AUROC (all and moving windows), the share "
                                  "of the unknown's moving windows flagged, the false alarms on the known "
                                  "classes' held-out runs and their balanced accuracy. Needs 3 classes with "
                                  ">= 2 runs."),
    windows: Optional[str] = typer.Option(None, "--windows", help="With --open-set, when --data is a folder and "
                                          "no model folder is given: window spec (default short; chunks with "
                                          "--format borealtc)."),
    folds: int = typer.Option(5, "--folds", help="With --open-set: outer grouped CV folds (by run)."),
    seed: int = typer.Option(0, "--seed", help="With --open-set: seed of folds, models and inner folds."),
    robot: Optional[str] = typer.Option(None, "--robot", help="With --open-set: robot spec when building "
                                        "from logs without a model folder."),
    preset: str = typer.Option("robust", "--preset", help="With --open-set: estimation preset when building "
                               "from logs without a model folder."),
    n_jobs: int = typer.Option(1, "--n-jobs", "-j", help="Parallel jobs when building from logs (with "
                               "--open-set: also over folds)."),
    dask_address: Optional[str] = typer.Option(None, "--dask-address", help="Dask scheduler for building."),
    fmt: str = typer.Option("auto", "--format", help="auto or borealtc (when --data is a folder)."),
    novelty_false_alarm: float = typer.Option(DEFAULT_FALSE_ALARM, "--novelty-false-alarm",
                                              help="With --open-set: " + _NOVELTY_FALSE_ALARM_HELP),
    trusted_key: Optional[List[Path]] = typer.Option(None, "--trusted-key", help=_TRUSTED_KEY_HELP),
    class_map: Optional[str] = typer.Option(None, "--class-map", help="Data class = model class, e.g. "
                                            "CONCRETE=ASPHALT,...: classes are matched by name; a data class "
                                            "the model lacks is refused unless mapped here."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print errors only."),
) -> None:
    """Score a saved model (verified on load) on other data; classes matched by name. With
    ``--open-set``: how well the novelty score finds ground the model was never trained on.

    Example: ``terrainml evaluate runs/svm --data data/sim_seed2 --out runs/svm/eval_seed2.json``

    Example (signed models only): ``terrainml evaluate runs/svm --data data/sim_seed2 --trusted-key release.pub``

    Example (unknown ground): ``terrainml evaluate --open-set --data ../shared/datasets/borealtc --format
    borealtc --model hgb --out runs/open_set_boreal``
    """
    check_n_jobs(n_jobs)
    if open_set:
        _check_false_alarm_option(novelty_false_alarm)
        _evaluate_open_set(model_dir, data, out, model=model, windows=windows, folds=folds, seed=seed, robot=robot,
                           preset=preset, n_jobs=n_jobs, dask_address=dask_address, fmt=fmt,
                           trusted_key=trusted_key, false_alarm=novelty_false_alarm, quiet=quiet)
        return
    if model_dir is None:
        fail("give the model folder (MODEL_DIR), or --open-set to evaluate unknown-ground detection")
    _evaluate_model(model_dir, data, out, model=model, n_jobs=n_jobs, dask_address=dask_address, fmt=fmt,
                    trusted_key=trusted_key, class_map=class_map, quiet=quiet)


def _evaluate_model(model_dir: Path, data: Path, out: Optional[Path], *, model, n_jobs: int, dask_address, fmt: str,
                    trusted_key, class_map, quiet: bool) -> None:
    """``evaluate MODEL_DIR``: the saved model's metrics on other data."""
    from terrainml.models.artifacts import ArtifactError, read_manifest
    from terrainml.models.signing import SignatureError, verify_artifact_signature
    from terrainml.pipeline.train import evaluate as do_eval

    if out is not None:
        check_output_writable(out)
    try:
        if trusted_key:  # origin before anything else is read
            verify_artifact_signature(model_dir, trusted_key)
        manifest = read_manifest(model_dir)
        from terrainml.features.windows import WindowSpec
        from terrainml.robot import RobotSpec

        rb = RobotSpec.from_dict(manifest["robot"]["spec"])
        spec = WindowSpec.from_dict(manifest["window_spec"])
        ds = _load_data(data, robot=rb, preset=manifest.get("preset", "robust"), n_jobs=n_jobs,
                        dask_address=dask_address, fmt=fmt, spec=spec, quiet=quiet)
        from terrainml.pipeline.train import parse_class_map

        m = do_eval(model_dir, ds, model, class_map=parse_class_map(class_map))
    except typer.Exit:
        raise
    except (ArtifactError, SignatureError) as exc:  # the message names the file or folder
        fail(str(exc))
    except Exception as exc:  # noqa: BLE001
        fail(f"{type(exc).__name__}: {exc}")
    from terrainml.models.artifacts import json_safe

    text = json.dumps(json_safe(m), indent=2, sort_keys=True) + "\n"
    if out is None:
        print(text, end="")
    else:
        out.parent.mkdir(parents=True, exist_ok=True)
        write_text(out, text)
    if not quiet:
        dse = m.get("desired_slip_error_mean")
        console.print(f"{m['model']} on {m['n_windows']} windows: balanced accuracy {m['balanced_accuracy']:.3f}, "
                      f"accuracy {m['accuracy']:.3f}, macro-F1 {m['macro_f1']:.3f}, desired-slip error "
                      f"{'n/a' if dse is None or dse != dse else f'{dse:.4f}'}"
                      + (f"; [green]wrote[/] {out}" if out else ""), highlight=False)


def _open_set_inputs(model_dir: Optional[Path], *, model, windows, robot, preset: str, fmt: str, trusted_key):
    """(model kind, window spec, robot, preset) of ``evaluate --open-set``: a model folder's (verified
    on load), else the options'. Exits 2 naming the folder or the option."""
    from terrainml.commands.dataset_cmds import window_spec_from_options
    from terrainml.features.windows import WindowSpec
    from terrainml.models.artifacts import ArtifactError, read_manifest
    from terrainml.models.signing import SignatureError, verify_artifact_signature
    from terrainml.robot import RobotSpec

    if model_dir is None:
        try:
            return model or "svm", window_spec_from_options(windows or ("chunks" if fmt == "borealtc" else "short")), \
                robot, preset
        except ValueError as exc:
            fail(f"--windows: {exc}")
    if windows is not None or robot is not None:
        fail("--windows and --robot come from the model folder; give them only without MODEL_DIR")
    try:
        if trusted_key:
            verify_artifact_signature(model_dir, trusted_key)
        manifest = read_manifest(model_dir)
    except (ArtifactError, SignatureError) as exc:
        fail(str(exc))
    kind = model or manifest["default_model"]
    if kind not in manifest.get("models", {}):
        fail(f"{model_dir}: no model {kind!r} (has {', '.join(manifest.get('models', {}))})")
    return (kind, WindowSpec.from_dict(manifest["window_spec"]), RobotSpec.from_dict(manifest["robot"]["spec"]),
            manifest.get("preset", "robust"))


def _evaluate_open_set(model_dir: Optional[Path], data: Path, out: Optional[Path], *, model, windows, folds: int,
                       seed: int, robot, preset: str, n_jobs: int, dask_address, fmt: str, trusted_key,
                       false_alarm: float, quiet: bool) -> None:
    """``evaluate --open-set``: the leave-one-class-out table on stdout, the report in ``out``."""
    from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    from terrainml.evaluation.open_set import open_set_markdown
    from terrainml.evaluation.report import OPEN_SET_FILES, write_open_set_report
    from terrainml.pipeline.train import evaluate_open_set

    if folds < 2:
        fail("--folds must be >= 2")
    if out is not None:
        check_output_writable(out, folder=True)
    kind, spec, rb, preset = _open_set_inputs(model_dir, model=model, windows=windows, robot=robot, preset=preset,
                                              fmt=fmt, trusted_key=trusted_key)
    try:
        ds = _load_data(data, robot=rb, preset=preset, n_jobs=n_jobs, dask_address=dask_address, fmt=fmt,
                        spec=spec, quiet=quiet)
        with Progress(SpinnerColumn(), TextColumn("[bold]evaluate[/] {task.description}"), TimeElapsedColumn(),
                      console=console, transient=True, disable=quiet) as progress:
            task = progress.add_task("", total=None)
            res = evaluate_open_set(ds, kind, folds=folds, seed=seed, n_jobs=n_jobs, false_alarm=false_alarm,
                                    progress=lambda msg: progress.update(task, description=msg))
        context = {"data": str(data), "model": kind, "window_spec": ds.spec.name, "robot": ds.robot.name,
                   "windows": int(len(ds.windows)), "runs": int(len(set(ds.windows.groups.tolist()))),
                   "model_dir": None if model_dir is None else str(model_dir)}
        if out is not None:
            write_open_set_report(out, res, context)
    except typer.Exit:
        raise
    except Exception as exc:  # noqa: BLE001 - a message, never a traceback
        fail(failure_message(data, exc, out))
    print("\n".join(open_set_markdown(res)))
    if not quiet:
        m = res.means()
        console.print(f"{kind} ({ds.spec.name} windows), leave-one-class-out over {len(res.table)} classes: mean "
                      f"AUROC {m['auroc']:.3f} (moving {m['auroc_moving']:.3f}), unknown's moving windows "
                      f"flagged {100 * m['unknown_flagged']:.1f}%, false alarms {100 * m['false_alarm']:.1f}% "
                      f"(reach at {100 * res.settings['reach_false_alarm']:.0f}% false alarms: "
                      f"{100 * m['unknown_flagged_reach']:.1f}%)"
                      + (f"; [green]wrote[/] {', '.join(str(out / f) for f in OPEN_SET_FILES)}" if out else ""),
                      highlight=False)


@model_app.command("keygen")
def keygen(out: Path = typer.Option(..., "--out", "-o", help="Private key file to create (PEM); the public "
                                    "key goes to OUT.pub.")) -> None:
    """Create an ed25519 key pair for signing model folders: OUT (private, mode 0600) and OUT.pub.

    Example: ``terrainml model keygen --out keys/release`` (keep keys/release secret; ship keys/release.pub)
    """
    from terrainml.models.signing import generate_keypair, key_fingerprint, load_public_key, public_key_path

    for p in (out, public_key_path(out)):
        if p.exists():
            fail(f"{p}: already exists; not overwriting a key")
        check_output_writable(p)
    out.parent.mkdir(parents=True, exist_ok=True)
    try:
        priv, pub = generate_keypair(out)
    except OSError as exc:
        fail(f"{out}: cannot write the key ({exc})")
    console.print(f"[green]wrote[/] {priv} (private: keep it secret) and {pub} (public: give it to "
                  f"`--trusted-key`); fingerprint {key_fingerprint(load_public_key(pub))[:16]}", highlight=False)


@model_app.command("sign")
def sign(
    model_dir: Path = typer.Argument(..., help="Model folder written by `terrainml train`."),
    key: Path = typer.Option(..., "--key", "-k", help="Private key (PEM) from `terrainml model keygen`."),
) -> None:
    """Verify a model folder (every file's sha256), then sign its manifest (manifest.sig).

    Example: ``terrainml model sign runs/svm --key keys/release``
    """
    from terrainml.models.artifacts import ArtifactError, verify_artifact
    from terrainml.models.signing import SignatureError, sign_artifact

    try:
        verify_artifact(model_dir)   # never sign a folder whose files no longer match its manifest
        path = sign_artifact(model_dir, key)
    except (ArtifactError, SignatureError) as exc:
        fail(str(exc))
    except OSError as exc:
        fail(f"{model_dir}: cannot write the signature ({exc})")
    console.print(f"[green]signed[/] {model_dir}: wrote {path}", highlight=False)


@model_app.command("verify")
def verify(
    model_dir: Path = typer.Argument(..., help="Model folder."),
    trusted_key: List[Path] = typer.Option(..., "--trusted-key", help=_TRUSTED_KEY_HELP),
) -> None:
    """Check a model folder's files and its signature by one of the trusted keys (exit 2 if not).

    Example: ``terrainml model verify runs/svm --trusted-key keys/release.pub``
    """
    from terrainml.models.artifacts import ArtifactError, verify_artifact
    from terrainml.models.signing import SignatureError, verify_artifact_signature

    try:
        fp = verify_artifact_signature(model_dir, trusted_key)
        verify_artifact(model_dir)
    except (ArtifactError, SignatureError) as exc:
        fail(str(exc))
    console.print(f"[green]ok[/] {model_dir}: files match the manifest, signed by trusted key {fp[:16]}",
                  highlight=False)


def register(app: typer.Typer) -> None:
    """Add this area's commands to the top-level app."""
    app.command("train")(train)
    app.command("evaluate")(evaluate)
    app.add_typer(model_app, name="model")
