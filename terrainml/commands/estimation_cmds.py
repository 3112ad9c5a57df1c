"""``terrainml estimate``: EKF + slip + dynamic state + NIS over one run (SYSTEM §7, §15)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import typer


def register(app: typer.Typer) -> None:
    """Add the estimation command to the top-level app."""

    @app.command("estimate")
    def estimate(
        run: Path = typer.Argument(..., help="Run log or table: .mcap, .bag, .csv or canonical .parquet."),
        out: Path = typer.Option(..., "--out", "-o", help="Output EST table (.parquet)."),
        preset: str = typer.Option("robust", help="EKF preset: thesis (eq. 6.9-6.14) or robust."),
        robot: Optional[str] = typer.Option(None, help="Robot spec YAML or built-in name "
                                            "(default: spec stored in the run, else agrimaro)."),
        plot: Optional[Path] = typer.Option(None, help="Folder for figures (like thesis Fig. 6.1-6.6, 7.2-7.4)."),
        topics: Optional[str] = typer.Option(None, help="Topic map YAML (or built-in name) for .mcap/.bag "
                                             "logs whose topics differ from the defaults."),
    ) -> None:
        """Estimate body velocity, per-wheel slip and wheel state for one run.

        Writes the EST table (contract 2) and, next to it, ``<out>.report.json`` with the
        consistency report (mean NIS/dof, fraction in the 95% chi-square band, innovation
        variances) and, when the run carries simulator truth (gt_* columns), per-wheel steady
        slip MAE, body-velocity RMSE and yaw-rate RMSE.

        Example: ``terrainml estimate runs/sim/run_000.mcap --out runs/est/run_000.parquet --plot runs/est/plots``

        Real Husky log: ``terrainml estimate test1.bag --robot husky --topics husky_robot_localization --out est.parquet``
        """
        from rich.console import Console
        from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn
        from rich.table import Table

        console = Console(stderr=True, soft_wrap=True)
        from terrainml.estimation.ekf import PRESETS

        if preset not in PRESETS:
            _fail(console, f"--preset must be one of {', '.join(PRESETS)}, got {preset!r}")
            raise typer.Exit(2)
        try:
            table = _load(run, robot, topics)
        except Exception as exc:  # noqa: BLE001 - any reader error becomes a clear message
            _fail(console, f"{run}: cannot read run: {exc}")
            raise typer.Exit(2) from None
        from terrainml.estimation.consistency import consistency_report, truth_metrics
        from terrainml.estimation.run import _robot_for, estimate_run_detailed
        from terrainml.robot import RobotSpecError

        try:
            spec = _robot_for(table, robot)
        except (RobotSpecError, ValueError) as exc:
            _fail(console, f"{exc}")
            raise typer.Exit(2) from None
        with Progress(TextColumn("[bold]estimate[/bold] {task.description}"), BarColumn(),
                      TextColumn("{task.percentage:>3.0f}%"), TimeRemainingColumn(),
                      console=console, transient=True) as prog:
            task = prog.add_task(run.name, total=len(table))
            try:
                est, diag = estimate_run_detailed(
                    table, spec, preset, progress=lambda k, n: prog.update(task, completed=k))
            except ValueError as exc:
                _fail(console, f"{run}: {exc}")
                raise typer.Exit(2) from None
        from terrainml.schema import write_run_parquet

        write_run_parquet(est, out)
        report = {"run": str(run), "preset": preset, "robot": spec.name, "n_ticks": len(est),
                  "consistency": consistency_report(est, diag)}
        if any(c.startswith("gt_") for c in est.columns):
            report["truth"] = truth_metrics(est, spec.n_wheels)
        rep_path = out.with_suffix(".report.json")
        rep_path.write_text(json.dumps(report, indent=2, default=float))
        _print_report(console, report, Table)
        if plot is not None:
            from terrainml.estimation.plots import save_plots

            files = save_plots(table, est, diag, spec, plot)
            console.print(f"wrote {len(files)} figures to {plot}")
        console.print(f"wrote {out} ({len(est)} ticks) and {rep_path}")


def _fail(console, message: str) -> None:
    """Print one clear error line (no wrapping inside paths)."""
    console.print(f"[red]error:[/red] {message}", soft_wrap=True)


def _load(run: Path, robot: Optional[str], topics: Optional[str] = None):
    if not run.exists():
        raise FileNotFoundError("file not found")
    if run.suffix == ".parquet":
        from terrainml.schema import read_run_parquet

        return read_run_parquet(run)
    try:
        from terrainml.io.ingest import load_run
    except ImportError as exc:  # pragma: no cover - until the io area lands
        raise RuntimeError(f"reading {run.suffix} needs terrainml.io.ingest ({exc})") from None
    res = load_run(run, robot=robot, topic_map=topics)
    if not getattr(res.report, "usable", True):
        why = "; ".join(getattr(res.report, "errors", []) or []) or "no usable sensor data"
        raise RuntimeError(f"ingest found no usable data: {why}")
    return res.table


def _print_report(console, report: dict, Table) -> None:
    c = report["consistency"]
    t = Table(title=f"EKF consistency ({report['preset']})")
    t.add_column("metric")
    t.add_column("value", justify="right")
    t.add_row("mean NIS/dof", f"{c['mean_nis_per_dof']:.3f}")
    t.add_row("median NIS/dof", f"{c['median_nis_per_dof']:.3f}")
    t.add_row("fraction in 95% band", f"{c['frac_in_95_band']:.3f}")
    for name, s in c.get("innovations", {}).items():
        t.add_row(f"innovation var {name}", f"{s['var']:.2e}")
    console.print(t)
    tr = report.get("truth")
    if tr:
        t = Table(title="accuracy against simulator truth")
        t.add_column("metric")
        t.add_column("value", justify="right")
        for i, v in enumerate(tr.get("steady_slip_mae_per_wheel", []), start=1):
            t.add_row(f"steady slip MAE wheel {i}", f"{v:.4f}")
        if "vel_rmse_mps" in tr:
            t.add_row("body-velocity RMSE [m/s]", f"{tr['vel_rmse_mps']:.4f}")
        if "yaw_rate_rmse_radps" in tr:
            t.add_row("yaw-rate RMSE [rad/s]", f"{tr['yaw_rate_rmse_radps']:.4f}")
        if "state_agreement" in tr:
            t.add_row("dynamic-state agreement", f"{tr['state_agreement']:.3f}")
        console.print(t)
