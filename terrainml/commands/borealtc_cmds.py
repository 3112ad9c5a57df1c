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

console = Console(stderr=True, soft_wrap=True)

PROTOCOLS = ("a", "b", "both")
MODELS = ("svm", "hgb", "cnn", "authors-svm")


def _fail(msg: str) -> None:
    console.print(f"[red]error:[/] {msg}", highlight=False)
    raise typer.Exit(2)


def evaluate_protocol_cmd(
    source: Path = typer.Argument(..., help="BorealTC folder: <CLASS>/imu_XX.csv and <CLASS>/pro_XX.csv."),
    protocol: str = typer.Option("both", "--protocol", "-p", help="a (authors': stratified 5-fold over "
                                 "5-s chunks), b (grouped by run) or both."),
    models: str = typer.Option("svm", "--models", "-m", help="Comma-separated: svm, hgb, cnn, authors-svm; A+B averages the out-of-fold probabilities of A and B (e.g. svm+hgb)."),
    window_s: float = typer.Option(1.7, "--window-s", help="Window length (s)."),
    chunk_s: float = typer.Option(5.0, "--chunk-s", help="Chunk length (s) of protocol (a)."),
    per_chunk: int = typer.Option(11, "--windows-per-chunk", help="Windows per chunk of the smallest "
                                  "class (the authors use 33: a 0.1-s stride)."),
    folds: int = typer.Option(5, "--folds", help="Outer folds."),
    seed_a: int = typer.Option(21, "--seed-a", help="Fold seed of protocol (a) (21 = the authors')."),
    seed_b: int = typer.Option(0, "--seed-b", help="Fold seed of protocol (b)."),
    robot: str = typer.Option("husky", "--robot", help="Robot spec YAML or built-in name."),
    quick: bool = typer.Option(False, "--quick", help="Smaller SVM grid and shorter CNN training."),
    n_jobs: int = typer.Option(2, "--n-jobs", "-j", help="joblib jobs of the SVM's inner search."),
    out_json: Optional[Path] = typer.Option(None, "--json", help="Write the metrics (JSON) here."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print errors only."),
) -> None:
    """Evaluate models on a BorealTC folder under protocol (a) and/or (b).

    Prints accuracy, balanced accuracy, per-class recall and the confusion matrix of each
    model and protocol. Hyper-parameters are searched inside each training fold only.

    Example: ``terrainml evaluate-protocol ../shared/datasets/borealtc -p both -m svm,cnn --json r.json``
    """
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from terrainml.io.borealtc import BorealTCError, load_borealtc
    from terrainml.evaluation.protocols import (average_results, chunk_windows, evaluate_protocol, make_chunks,
                                            protocol_a_folds, protocol_b_folds, protocol_models)
    from terrainml.robot import RobotSpecError, load_robot

    if protocol not in PROTOCOLS:
        _fail(f"--protocol must be one of {', '.join(PROTOCOLS)}, got {protocol!r}")
    names = [m.strip() for m in models.split(",") if m.strip()]
    bad = [m for m in names if not all(q in MODELS for q in m.split("+"))]
    base_models = list(dict.fromkeys(q for m in names for q in m.split("+")))
    if bad or not names:
        _fail(f"--models: unknown {bad or models!r}; choose from {', '.join(MODELS)}")
    if not (window_s > 0 and chunk_s >= window_s):
        _fail(f"--window-s {window_s} must be > 0 and not longer than --chunk-s {chunk_s}")
    if per_chunk < 1 or folds < 2 or n_jobs == 0:
        _fail("--windows-per-chunk must be >= 1, --folds >= 2 and --n-jobs not 0")
    try:
        rb = load_robot(robot)
    except (RobotSpecError, OSError, ValueError) as exc:
        _fail(f"--robot {robot}: {exc}")
    try:
        tables, rep = load_borealtc(source, robot=rb)
    except BorealTCError as exc:
        _fail(str(exc))
    if not tables:
        _fail(f"{source}: no run could be read ({rep.skipped})")
    chunks = make_chunks(tables, chunk_s=chunk_s)
    if len(chunks) == 0:
        _fail(f"{source}: no complete {chunk_s:g}-s chunk with valid IMU and wheel data")
    W = chunk_windows(tables, chunks, window_s=window_s, max_windows_per_chunk=per_chunk)
    if not quiet:
        console.print(f"{source}: {rep.runs} runs, classes {rep.classes}; runs without IMU (no chunk): "
                      f"{chunks.runs_without_chunks or 'none'}; {len(chunks)} chunks, {len(W)} windows",
                      highlight=False)
    wheels = rb.wheels
    track = float(abs(wheels[0].y_m - wheels[1].y_m)) if len(wheels) > 1 else 0.5708
    fac = protocol_models(quick, track, n_jobs=n_jobs)
    todo = [p for p in ("a", "b") if protocol in (p, "both")]
    if len(set(W.meta["terrain"])) < 2:
        _fail(f"{source}: need at least two terrain classes with chunks")
    results = {}
    with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                  TimeElapsedColumn(), console=console, transient=True, disable=quiet) as progress:
        for p in todo:
            try:
                folds_ = protocol_a_folds(W, folds, seed_a) if p == "a" else protocol_b_folds(W, folds, seed_b)
            except ValueError as exc:
                _fail(f"{source}: protocol ({p}) folds: {exc}")
            inner = W.meta["chunk_id"].to_numpy() if p == "a" else W.meta["run_id"].astype(str).to_numpy()
            done = {}
            for m in base_models:
                task = progress.add_task(f"protocol ({p}) {m}", total=len(folds_))
                done[m] = evaluate_protocol(fac[m], W, folds_, inner_groups=inner, class_names=rep.classes,
                                            name=f"({p}) {m}", split_groups=inner,
                                            progress=lambda k, n, t=task: progress.update(t, completed=k))
            for m in names:
                parts = m.split("+")
                results[(p, m)] = (done[m] if len(parts) == 1 else
                                   average_results([done[q] for q in parts], name=f"({p}) {m}"))
    for (p, m), res in results.items():
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
        Console().print(t)
    if out_json is not None:
        payload = {f"{p}:{m}": {"accuracy": r.accuracy, "balanced_accuracy": r.balanced_accuracy,
                                "recall_per_class": r.recall_per_class(),
                                "confusion_matrix": r.pooled["confusion_matrix"], "classes": r.class_names,
                                "folds": [{k: v for k, v in f.items() if k != "best_params"} |
                                          {"best_params": {k: str(v) for k, v in f["best_params"].items()}}
                                          for f in r.fold_metrics]}
                   for (p, m), r in results.items()}
        payload["_setup"] = {"source": str(source), "window_s": window_s, "chunk_s": chunk_s,
                             "windows_per_chunk": per_chunk, "n_windows": len(W), "n_chunks": len(chunks),
                             "runs_without_chunks": chunks.runs_without_chunks, "quick": quick}
        try:
            out_json.write_text(json.dumps(payload, indent=2))
        except OSError as exc:
            _fail(f"{out_json}: cannot write ({exc})")
        if not quiet:
            console.print(f"[green]wrote[/] {out_json}", highlight=False)


def register(app: typer.Typer) -> None:
    """Add ``evaluate-protocol`` to the top-level app."""
    app.command("evaluate-protocol")(evaluate_protocol_cmd)
