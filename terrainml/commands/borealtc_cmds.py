"""CLI command ``terrainml evaluate-protocol``: the two BorealTC evaluation protocols.

Exit codes: 0 on success, 2 when the input is unusable (message names the folder or file);
never a traceback.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.table import Table

from terrainml.atomic import write_text
from terrainml.commands._common import check_n_jobs, check_output_writable, console, fail, open_robot
from terrainml.commands._help import robot_help

PROTOCOLS = ("a", "b", "both")


def evaluate_protocol_cmd(
    source: Path = typer.Argument(..., help="BorealTC folder: <CLASS>/imu_XX.csv and <CLASS>/pro_XX.csv."),
    protocol: str = typer.Option("both", "--protocol", "-p", help="a (authors': stratified 5-fold over "
                                 "5-s chunks), b (grouped by run) or both."),
    models: str = typer.Option("svm", "--models", "-m", help="Comma-separated: svm, hgb, cnn, authors-svm; "
                               "A+B averages the out-of-fold probabilities of A and B (e.g. svm+hgb)."),
    window_s: float = typer.Option(1.7, "--window-s", help="Window length (s)."),
    chunk_s: float = typer.Option(5.0, "--chunk-s", help="Chunk length (s) of protocol (a)."),
    per_chunk: int = typer.Option(11, "--windows-per-chunk", help="Windows per chunk of the smallest "
                                  "class (the authors use 33: a 0.1-s stride)."),
    folds: int = typer.Option(5, "--folds", help="Outer folds."),
    seed_a: int = typer.Option(21, "--seed-a", help="Fold seed of protocol (a) (21 = the authors')."),
    seed_b: int = typer.Option(0, "--seed-b", help="Fold seed of protocol (b)."),
    robot: str = typer.Option("husky", "--robot", help=robot_help(None)),
    quick: bool = typer.Option(False, "--quick", help="Smaller SVM grid and shorter CNN training."),
    n_jobs: int = typer.Option(2, "--n-jobs", "-j", help="joblib jobs of the SVM's inner search."),
    out_json: Optional[Path] = typer.Option(None, "--json", help="Write the metrics (JSON) here."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print errors only."),
) -> None:
    """Evaluate models on a BorealTC folder under protocol (a) and/or (b).

    Prints accuracy, balanced accuracy, per-class recall and the confusion matrix of each
    model and protocol. Hyper-parameters are searched inside each training fold only.

    Example: terrainml evaluate-protocol ../shared/datasets/borealtc -p both -m svm,cnn --json r.json
    """
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from terrainml.experiments.borealtc import MODELS, load_protocol_data, run_protocol
    from terrainml.io.ingest.dataset_spec import DatasetSpecError

    if protocol not in PROTOCOLS:
        fail(f"--protocol must be one of {', '.join(PROTOCOLS)}, got {protocol!r}")
    names = [m.strip() for m in models.split(",") if m.strip()]
    bad = [m for m in names if not all(q in MODELS for q in m.split("+"))]
    if bad or not names:
        fail(f"--models: unknown {bad or models!r}; choose from {', '.join(MODELS)}")
    if not (window_s > 0 and chunk_s >= window_s):
        fail(f"--window-s {window_s} must be > 0 and not longer than --chunk-s {chunk_s}")
    if per_chunk < 1 or folds < 2:
        fail("--windows-per-chunk must be >= 1 and --folds >= 2")
    check_n_jobs(n_jobs)
    rb = open_robot(robot)
    if out_json is not None:
        check_output_writable(out_json)
    try:
        data = load_protocol_data(source, rb, chunk_s=chunk_s, window_s=window_s, max_windows_per_chunk=per_chunk)
    except (DatasetSpecError, ValueError) as exc:
        fail(str(exc))
    W, chunks = data.windows, data.chunks
    if not quiet:
        console.print(f"{source}: {data.report.runs} runs, classes {data.report.classes}; runs without IMU "
                      f"(no chunk): {chunks.runs_without_chunks or 'none'}; {len(chunks)} chunks, {len(W)} windows",
                      highlight=False)
    if len(set(W.meta["terrain"])) < 2:
        fail(f"{source}: need at least two terrain classes with chunks")
    results = {}
    with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                  TimeElapsedColumn(), console=console, transient=True, disable=quiet) as progress:
        for p in [p for p in ("a", "b") if protocol in (p, "both")]:
            tasks: dict[str, int] = {}

            def tick(model: str, k: int, n: int, p: str = p, tasks: dict = tasks) -> None:
                if model not in tasks:
                    tasks[model] = progress.add_task(f"protocol ({p}) {model}", total=n)
                progress.update(tasks[model], completed=k)

            try:
                res = run_protocol(data, p, names, n_splits=folds, seed=seed_a if p == "a" else seed_b,
                                   quick=quick, n_jobs=n_jobs, progress=tick)
            except ValueError as exc:
                fail(f"{source}: protocol ({p}): {exc}")
            results.update({(p, m): r for m, r in res.items()})
    # stdout, at the tables' natural width: a narrow terminal or a pipe would cut the class names
    out = Console(width=max(Console().width, 200))
    for (p, m), res in results.items():
        out.print(_confusion_table(p, m, res))
    if out_json is not None:
        setup = {"source": str(source), "window_s": window_s, "chunk_s": chunk_s,
                 "windows_per_chunk": per_chunk, "n_windows": len(W), "n_chunks": len(chunks),
                 "runs_without_chunks": chunks.runs_without_chunks, "quick": quick}
        _write_json(out_json, results, setup, quiet)


def _confusion_table(p: str, m: str, res) -> Table:
    """Protocol ``p``, model ``m``: accuracies in the title, confusion matrix and recall per class."""
    t = Table(title=f"protocol ({p}) {m}: accuracy {100 * res.accuracy:.2f}%, balanced "
                    f"{100 * res.balanced_accuracy:.2f}%", title_justify="left")
    t.add_column("true \\ predicted")
    for c in res.class_names:
        t.add_column(c, justify="right")
    t.add_column("recall %", justify="right")
    cm = res.confusion_frame()
    rec = res.recall_per_class()
    for c in res.class_names:
        t.add_row(c, *[str(int(v)) for v in cm.loc[c]], f"{100 * rec[c]:.1f}")
    return t


def _write_json(out_json: Path, results: dict, setup: dict, quiet: bool) -> None:
    """The metrics of every (protocol, model) and the setup, as JSON (``--json``)."""
    payload = {f"{p}:{m}": {"accuracy": r.accuracy, "balanced_accuracy": r.balanced_accuracy,
                            "recall_per_class": r.recall_per_class(),
                            "confusion_matrix": r.pooled["confusion_matrix"], "classes": r.class_names,
                            "folds": [_fold_json(f) for f in r.fold_metrics]}
               for (p, m), r in results.items()}
    payload["_setup"] = setup
    try:
        write_text(out_json, json.dumps(payload, indent=2))
    except OSError as exc:
        fail(f"{out_json}: cannot write ({exc})")
    if not quiet:
        console.print(f"[green]wrote[/] {out_json}", highlight=False)


def _fold_json(m: dict) -> dict:
    """One fold's entry of the JSON file: sizes, accuracies, fit time, chosen parameters (as text)."""
    return {"fold": m["fold"], "n_test": m["n_windows"], "accuracy": m["accuracy"],
            "balanced_accuracy": m["balanced_accuracy"], "fit_time_s": m["fit_time_s"],
            "best_params": {k: str(v) for k, v in m["best_params"].items()}}


def register(app: typer.Typer) -> None:
    """Add ``evaluate-protocol`` to the top-level app."""
    app.command("evaluate-protocol")(evaluate_protocol_cmd)
