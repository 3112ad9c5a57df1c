"""``terrainml evaluate``: a saved model (verified on load) scored on other data, or with
``--open-set`` how well the novelty score finds ground the model was never trained on.

Exit codes: 0 on success, 2 when the data or the model folder is unusable (message names the
file); never a traceback. Outputs and ``--n-jobs`` are checked before any long work.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import List, Optional

import typer

from terrainml.atomic import write_text
from terrainml.commands._help import robot_help
from terrainml.commands._common import (check_n_jobs, check_output_writable, console, fail, failure_message,
                                        is_windows_file)
from terrainml.commands._model_inputs import (NOVELTY_FALSE_ALARM_HELP, TRUSTED_KEY_HELP,
                                              check_novelty_false_alarm_option, load_data, load_tables)
from terrainml.models.novelty_target import DEFAULT_FALSE_ALARM


def evaluate(
    model_dir: Optional[Path] = typer.Argument(None, help="Model folder written by 'terrainml train' (with "
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
    robot: Optional[str] = typer.Option(None, "--robot", help="With --open-set, building from logs without a "
                                        "model folder: " + robot_help(None)),
    preset: str = typer.Option("robust", "--preset", help="With --open-set: estimation preset when building "
                               "from logs without a model folder."),
    n_jobs: int = typer.Option(1, "--n-jobs", "-j", help="Parallel jobs when building from logs (with "
                               "--open-set: also over folds)."),
    dask_address: Optional[str] = typer.Option(None, "--dask-address", help="Dask scheduler for building."),
    fmt: str = typer.Option("auto", "--format", help="auto or borealtc (when --data is a folder)."),
    novelty_false_alarm: float = typer.Option(DEFAULT_FALSE_ALARM, "--novelty-false-alarm",
                                              help="With --open-set: " + NOVELTY_FALSE_ALARM_HELP),
    trusted_key: Optional[List[Path]] = typer.Option(None, "--trusted-key", help=TRUSTED_KEY_HELP),
    class_map: Optional[str] = typer.Option(None, "--class-map", help="Data class = model class, e.g. "
                                            "CONCRETE=ASPHALT,...: classes are matched by name; a data class "
                                            "the model lacks is refused unless mapped here."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print errors only."),
) -> None:
    """Score a saved model (verified on load) on other data; classes matched by name. With
    --open-set: how well the novelty score finds ground the model was never trained on.

    Example: terrainml evaluate runs/svm --data data/sim_seed2 --out runs/svm/eval_seed2.json

    Example (signed models only): terrainml evaluate runs/svm --data data/sim_seed2 --trusted-key release.pub

    Example (unknown ground): terrainml evaluate --open-set --data ../shared/datasets/borealtc --format
    borealtc --model hgb --out runs/open_set_boreal
    """
    check_n_jobs(n_jobs)
    if open_set:
        check_novelty_false_alarm_option(novelty_false_alarm)
        if folds < 2:
            fail("--folds must be >= 2")
        from terrainml.pipeline.train_options import TrainOptions

        options = TrainOptions(folds=folds, seed=seed, n_jobs=n_jobs, novelty_false_alarm=novelty_false_alarm)
        _evaluate_open_set(model_dir, data, out, options, model=model, windows=windows, robot=robot, preset=preset,
                           dask_address=dask_address, fmt=fmt, trusted_key=trusted_key, quiet=quiet)
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
    from terrainml.pipeline.evaluate import evaluate as do_eval
    from terrainml.pipeline.evaluate import parse_class_map

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
        ds = load_data(data, robot=rb, preset=manifest.get("preset", "robust"), n_jobs=n_jobs,
                       dask_address=dask_address, fmt=fmt, spec=spec, quiet=quiet)
        # logs with labels are also served tick by tick, as train's served replay does
        tables = None if is_windows_file(data) else load_tables(data, robot=rb, fmt=fmt, quiet=True)[0]
        m = do_eval(model_dir, ds, model, class_map=parse_class_map(class_map), tables=tables)
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
        rep = m.get("served_replay")
        if rep and rep.get("moving_ticks"):
            from terrainml.stream.app.tick_losses import losses_sentence

            console.print(f"served replay ({rep['runs']} runs, {rep['moving_ticks']} moving ticks): class right on "
                          f"{rep['right_share']:.1%}; {losses_sentence(rep['losses'])}", highlight=False)


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


def _evaluate_open_set(model_dir: Optional[Path], data: Path, out: Optional[Path], options, *, model, windows,
                       robot, preset: str, dask_address, fmt: str, trusted_key, quiet: bool) -> None:
    """``evaluate --open-set``: the leave-one-class-out table on stdout, the report in ``out``;
    ``options``: :class:`~terrainml.pipeline.train_options.TrainOptions` (folds, seed, jobs, novelty target)."""
    from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    from terrainml.evaluation.open_set import open_set_markdown
    from terrainml.evaluation.report import OPEN_SET_FILES, write_open_set_report
    from terrainml.pipeline.train import evaluate_open_set

    if out is not None:
        check_output_writable(out, folder=True)
    kind, spec, rb, preset = _open_set_inputs(model_dir, model=model, windows=windows, robot=robot, preset=preset,
                                              fmt=fmt, trusted_key=trusted_key)
    try:
        ds = load_data(data, robot=rb, preset=preset, n_jobs=options.n_jobs, dask_address=dask_address, fmt=fmt,
                       spec=spec, quiet=quiet)
        with Progress(SpinnerColumn(), TextColumn("[bold]evaluate[/] {task.description}"), TimeElapsedColumn(),
                      console=console, transient=True, disable=quiet) as progress:
            task = progress.add_task("", total=None)
            res = evaluate_open_set(ds, kind, options, progress=lambda msg: progress.update(task, description=msg))
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
