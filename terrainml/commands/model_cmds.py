"""CLI commands of the models area: ``terrainml train`` and ``terrainml evaluate``.

Exit codes: 0 on success, 2 when the data or the model folder is unusable (message names the
file); never a traceback.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.table import Table

console = Console(stderr=True, soft_wrap=True)


def _fail(msg: str) -> None:
    console.print(f"[red]error:[/] {msg}", highlight=False)
    raise typer.Exit(2)


def _load_data(data: Path, *, robot, preset: str, n_jobs: int, dask_address, fmt: str, spec=None,
               quiet: bool = False):
    """A Dataset from a windows Parquet or (built first) a folder of logs."""
    from terrainml.pipeline.dataset import read_windows

    if data.is_file() and data.suffix == ".parquet":
        import pyarrow.parquet as pq

        md = pq.read_schema(data).metadata or {}
        if b"terrainml_windows" in md:
            return read_windows(data)
    from terrainml.commands.dataset_cmds import build_with_progress, rejection_table

    ds = build_with_progress(data, robot=robot, preset=preset, n_jobs=n_jobs, dask_address=dask_address,
                             fmt=fmt, quiet=quiet, spec=spec)
    if not quiet:
        console.print(rejection_table(ds))
    return ds


def train(
    data: Path = typer.Option(..., "--data", "-d", help="Windows Parquet (from `dataset build`) or a folder "
                              "of logs (the dataset is built first)."),
    out: Path = typer.Option(..., "--out", "-o", help="Model folder to create, e.g. runs/NAME."),
    model: str = typer.Option("svm", "--model", "-m", help="svm, cnn or all."),
    folds: int = typer.Option(5, "--folds", help="Outer grouped CV folds (by run)."),
    seed: int = typer.Option(0, "--seed", help="Seed of folds and models."),
    n_jobs: int = typer.Option(1, "--n-jobs", "-j", help="Parallel jobs (folds; logs when building)."),
    dask_address: Optional[str] = typer.Option(None, "--dask-address", help="Dask scheduler for building "
                                               "the dataset from logs (tcp://HOST:PORT)."),
    preset: str = typer.Option("robust", "--preset", help="Estimation preset when building from logs."),
    robot: Optional[str] = typer.Option(None, "--robot", help="Robot spec when building from logs."),
    fmt: str = typer.Option("auto", "--format", help="auto or borealtc (when --data is a folder)."),
    ablation: bool = typer.Option(True, "--ablation/--no-ablation", help="SVM feature-set ablation."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print errors only."),
) -> None:
    """Cross-validate (grouped by run), train, report and save a terrain classifier.

    Example: ``terrainml train --data data/windows.parquet --model svm --folds 5 --seed 0 --out runs/svm``

    Example (from logs, both models): ``terrainml train --data data/sim --model all --out runs/all``
    """
    from terrainml.pipeline.train import MODEL_KINDS
    from terrainml.pipeline.train import train as do_train

    kinds = list(MODEL_KINDS) if model == "all" else [m.strip() for m in model.split(",")]
    for k in kinds:
        if k not in MODEL_KINDS:
            _fail(f"unknown --model {k!r}; expected svm, cnn or all")
    if folds < 2:
        _fail("--folds must be >= 2")
    try:
        ds = _load_data(data, robot=robot, preset=preset, n_jobs=n_jobs, dask_address=dask_address,
                        fmt=fmt, quiet=quiet)
        from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

        with Progress(SpinnerColumn(), TextColumn("[bold]train[/] {task.description}"), TimeElapsedColumn(),
                      console=console, transient=True, disable=quiet) as progress:
            task = progress.add_task("", total=None)
            res = do_train(ds, out, kinds, folds=folds, seed=seed, n_jobs=n_jobs, ablation=ablation,
                           progress=lambda msg: progress.update(task, description=msg))
    except typer.Exit:
        raise
    except Exception as exc:  # noqa: BLE001 - a message, never a traceback
        _fail(f"{data}: {type(exc).__name__}: {exc}")
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
        console.print(f"[green]wrote[/] {out} (served model: {res.default_model}; report {out / 'report.md'})",
                      highlight=False)


def evaluate(
    model_dir: Path = typer.Argument(..., help="Model folder written by `terrainml train`."),
    data: Path = typer.Option(..., "--data", "-d", help="Windows Parquet or folder of logs to score on."),
    out: Optional[Path] = typer.Option(None, "--out", "-o", help="Write the metrics JSON here "
                                       "(stdout when omitted)."),
    model: Optional[str] = typer.Option(None, "--model", "-m", help="Model in the folder (default: the served one)."),
    n_jobs: int = typer.Option(1, "--n-jobs", "-j", help="Parallel jobs when building from logs."),
    dask_address: Optional[str] = typer.Option(None, "--dask-address", help="Dask scheduler for building."),
    fmt: str = typer.Option("auto", "--format", help="auto or borealtc (when --data is a folder)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print errors only."),
) -> None:
    """Score a saved model (verified on load) on other data.

    Example: ``terrainml evaluate runs/svm --data data/sim_seed2 --out runs/svm/eval_seed2.json``
    """
    from terrainml.models.artifacts import ArtifactError, read_manifest
    from terrainml.pipeline.train import evaluate as do_eval

    try:
        manifest = read_manifest(model_dir)
        from terrainml.features.windows import WindowSpec
        from terrainml.robot import RobotSpec

        rb = RobotSpec.from_dict(manifest["robot"]["spec"])
        spec = WindowSpec.from_dict(manifest["window_spec"])
        ds = _load_data(data, robot=rb, preset=manifest.get("preset", "robust"), n_jobs=n_jobs,
                        dask_address=dask_address, fmt=fmt, spec=spec, quiet=quiet)
        m = do_eval(model_dir, ds, model)
    except ArtifactError as exc:
        _fail(str(exc))
    except typer.Exit:
        raise
    except Exception as exc:  # noqa: BLE001
        _fail(f"{type(exc).__name__}: {exc}")
    from terrainml.models.artifacts import json_safe

    text = json.dumps(json_safe(m), indent=2, sort_keys=True) + "\n"
    if out is None:
        print(text, end="")
    else:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(text)
    if not quiet:
        dse = m.get("desired_slip_error_mean")
        console.print(f"{m['model']} on {m['n_windows']} windows: balanced accuracy {m['balanced_accuracy']:.3f}, "
                      f"accuracy {m['accuracy']:.3f}, macro-F1 {m['macro_f1']:.3f}, desired-slip error "
                      f"{'n/a' if dse is None or dse != dse else f'{dse:.4f}'}"
                      + (f"; [green]wrote[/] {out}" if out else ""), highlight=False)


def register(app: typer.Typer) -> None:
    """Add this area's commands to the top-level app."""
    app.command("train")(train)
    app.command("evaluate")(evaluate)
