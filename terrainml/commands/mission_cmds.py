"""CLI of the mission suite: ``terrainml mission list|run|plot`` (design §12, §15; docs/missions.md).

The simulator, the controllers and matplotlib are imported inside the commands so that
``terrainml --help`` stays fast.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, List, Optional

import typer
from rich.markup import escape
from rich.table import Table

from terrainml.atomic import write_text
from terrainml.commands._common import check_n_jobs, check_output_writable, console, fail

mission_app = typer.Typer(help="Mission suite: position-based missions that ask for traction.",
                          no_args_is_help=True)


def _json_ready(x: Any) -> Any:
    """NaN and inf become null (JSON has neither); numpy scalars become Python numbers."""
    if isinstance(x, dict):
        return {k: _json_ready(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_json_ready(v) for v in x]
    if hasattr(x, "item") and not isinstance(x, (str, bytes)):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


@mission_app.command("list", help=(
    "Name the mission suites with their terrains, seeds and number of missions.\n\n"
    "Example: terrainml mission list --seeds eval"))
def list_suites(
    seeds: str = typer.Option("eval", "--seeds", help="Seed set: eval (default, never for tuning) or tuning."),
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of a table."),
) -> None:
    from terrainml.experiments.missions import SEED_SETS, suite_counts

    if seeds not in SEED_SETS:
        fail(f"--seeds {seeds!r}: expected one of {', '.join(SEED_SETS)}")
    counts = suite_counts(seeds)
    if as_json:
        print(json.dumps(counts, indent=2))
        return
    t = Table(title=f"mission suites ({seeds} seeds)", title_justify="left")
    for col in ("suite", "terrains", "seeds", "missions"):
        t.add_column(col)
    for name, c in counts.items():
        t.add_row(name, ", ".join(c["terrains"]),
                  f"{c['n_seeds']} ({c['first_seed']}..{c['first_seed'] + c['n_seeds'] - 1})",
                  str(c["missions"]))
    from rich.console import Console

    Console(soft_wrap=True).print(t)


@mission_app.command("run", help=(
    "Run a mission suite under one traction-control policy and write a JSON report: a `missions` "
    "list (one row per mission: family, terrain, seed, parameters, success, time_s, distance_m, "
    "energy_j_per_m, spin_share, max_sinkage_m, demand_ratio, ...) and a `summary`.\n\n"
    "Policies: none, fixed (slip cap 0.1), terrain-aware (served by the predictor from --model), "
    "terrain-aware-closed (the same without its novelty score: never unknown_terrain), "
    "terrain-aware-refine-unknown (the safe cap on unknown ground refined online), "
    "oracle (true class), oracle-cap (true traction peak of the terrain draw under each wheel).\n\n"
    "Example: terrainml mission run --suite field --policy oracle-cap --n-jobs 2 --out field_cap.json"))
def run(
    suite_name: str = typer.Option(..., "--suite", help="greenhouse, field or all."),
    policy: str = typer.Option(..., "--policy", help="Traction-control policy (see above)."),
    model: Optional[Path] = typer.Option(None, "--model", help="Trained model folder (terrain-aware)."),
    limit: Optional[int] = typer.Option(None, "--limit", help="Run only the first N missions."),
    seeds: str = typer.Option("eval", "--seeds", help="Seed set: eval (default) or tuning."),
    held_out: Optional[str] = typer.Option(
        None, "--held-out",
        help="Open-set suite: only the missions whose ground has this class (base or patch), to drive a "
             "model trained without it (e.g. --held-out wet_mud --policy terrain-aware-closed, then "
             "terrain-aware, which serves the safe cap on ground its novelty score flags)."),
    n_jobs: int = typer.Option(1, "--n-jobs", "-j", help="Parallel missions (joblib; -1: all cores)."),
    traces: bool = typer.Option(False, "--traces", help="Also write a decimated trace per mission "
                                "(10 Hz) to REPORT.traces.npz, for `mission plot`."),
    out: Path = typer.Option(..., "--out", help="Write the JSON report here."),
) -> None:
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from terrainml.experiments.mission_metrics import summarise
    from terrainml.experiments.mission_policies import POLICIES
    from terrainml.experiments.missions import SEED_SETS, open_set_suite, run_suite, suite

    if policy not in POLICIES:
        fail(f"--policy {policy!r}: expected one of {', '.join(POLICIES)}")
    if seeds not in SEED_SETS:
        fail(f"--seeds {seeds!r}: expected one of {', '.join(SEED_SETS)}")
    if limit is not None and limit < 1:
        fail(f"--limit must be >= 1, got {limit}")
    if policy in ("terrain-aware", "terrain-aware-closed", "terrain-aware-refine-unknown") and model is None:
        fail(f"--policy {policy} needs --model (a trained model folder); "
             "--policy oracle is the same controller with the true class")
    if model is not None and not model.is_dir():
        fail(f"--model {model}: no such model folder")
    check_n_jobs(n_jobs)
    try:
        specs = suite(suite_name, seeds)
    except ValueError as exc:
        fail(f"--suite: {exc}")
    if held_out is not None:
        try:
            on_it = set(open_set_suite(held_out, seeds))
        except ValueError as exc:
            fail(f"--held-out: {exc}")
        specs = [m for m in specs if m in on_it]
    specs = specs[:limit]
    check_output_writable(out)
    npz = out.with_name(out.name.removesuffix(".json") + ".traces.npz")
    if traces:
        check_output_writable(npz)
    with Progress(TextColumn("[bold]mission[/] {task.description}"), BarColumn(), MofNCompleteColumn(),
                  TimeElapsedColumn(), console=console, transient=True) as bar:
        task = bar.add_task(f"{escape(suite_name)} / {escape(policy)}", total=len(specs))
        try:
            rows, logs = run_suite(specs, policy, model=model, n_jobs=n_jobs,
                                   trace_every=10 if traces else 0,
                                   progress=lambda k, n: bar.update(task, completed=k))
        except ValueError as exc:  # model refused, bad parameters
            fail(str(exc))
    report: dict[str, Any] = {"suite": suite_name, "held_out": held_out, "policy": policy, "seeds": seeds,
                              "model": str(model) if model is not None else None,
                              "missions": rows, "summary": summarise(rows)}
    out.parent.mkdir(parents=True, exist_ok=True)
    if traces:
        import numpy as np

        arrays = {f"{i}/{k}": v for i, lg in enumerate(logs) for k, v in lg.arrays().items()}
        np.savez_compressed(npz, **arrays)
        report["traces"] = npz.name
    write_text(out, json.dumps(_json_ready(report), indent=1) + "\n")
    s = report["summary"]["overall"]
    console.print(f"wrote {escape(str(out))}: {s['n']} missions, success {100 * s['success_rate']:.0f}%"
                  + (f", traces {escape(npz.name)}" if traces else ""), highlight=False)


@mission_app.command("plot", help=(
    "Draw mission reports: per traced mission the route over its patches, slip and sinkage over "
    "distance (needs `mission run --traces`), and success and energy per policy over all reports.\n\n"
    "Example: terrainml mission plot none.json cap.json --out figs/"))
def plot(
    reports: List[Path] = typer.Argument(..., help="Reports written by `terrainml mission run`."),
    out: Path = typer.Option(..., "--out", help="Output folder for the PNGs."),
    max_missions: int = typer.Option(12, "--max-missions", help="Traced missions drawn per report."),
) -> None:
    from terrainml.experiments.mission_plot import load_traces, plot_mission, plot_policies

    loaded = []
    for p in reports:
        if not p.is_file():
            fail(f"{p}: file not found")
        try:
            rep = json.loads(p.read_text())
        except (OSError, ValueError) as exc:
            fail(f"{p}: not a JSON report ({exc})")
        if not isinstance(rep, dict) or "missions" not in rep:
            fail(f"{p}: not a mission report (no 'missions' list)")
        loaded.append((p, rep))
    check_output_writable(out, folder=True)
    written = [plot_policies([r for _, r in loaded], out / "policies.png")]
    for p, rep in loaded:
        if not rep.get("traces"):
            continue
        npz = p.parent / rep["traces"]
        if not npz.is_file():
            fail(f"{npz}: trace file of {p} not found")
        traces = load_traces(npz)
        for i, row in enumerate(rep["missions"][:max_missions]):
            if i in traces:
                name = f"{p.stem}_{i:03d}_{row['family']}_{row['terrain']}_{row['seed']}.png"
                written.append(plot_mission(row, traces[i], out / name))
    console.print(f"wrote {len(written)} figures to {escape(str(out))}", highlight=False)


def register(app: typer.Typer) -> None:
    """Add this area's commands to the top-level app."""
    app.add_typer(mission_app, name="mission")
