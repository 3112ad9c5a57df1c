"""``terrainml estimate``: EKF + slip + dynamic state + NIS over one run (design §7, §15)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import typer
from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

from terrainml.atomic import write_text
from terrainml.commands._common import check_output_writable, console, fail, failure_message, open_robot, open_run
from terrainml.commands._help import robot_help, topics_help
from terrainml.robots import REFERENCE_ROBOT


def register(app: typer.Typer) -> None:
    """Add the estimation command to the top-level app."""

    @app.command("estimate")
    def estimate(
        run: Path = typer.Argument(..., help="Run log or table: .mcap, .bag, .csv or canonical .parquet."),
        out: Path = typer.Option(..., "--out", "-o", help="Output EST table (.parquet)."),
        preset: str = typer.Option("robust", help="EKF preset: thesis (eq. 6.9-6.14) or robust."),
        robot: Optional[str] = typer.Option(None, help=robot_help(
            f"the spec stored in the run, else {REFERENCE_ROBOT}")),
        plot: Optional[Path] = typer.Option(None, help="Folder for figures (like thesis Fig. 6.1-6.6, 7.2-7.4)."),
        topics: Optional[str] = typer.Option(None, help=topics_help() + " For .mcap/.bag logs."),
        reference: bool = typer.Option(False, "--reference", help="Run the readable numpy reference "
                                       "filter (terrainml.estimation.reference, the EKF's specification) "
                                       "instead of the compiled one: the same numbers, much slower; to "
                                       "check the compiled filter on your data."),
    ) -> None:
        """Estimate body velocity, per-wheel slip and wheel state for one run.

        Writes the EST table (contract 2) and, next to it, OUT.report.json with the
        consistency report (mean NIS/dof, fraction in the 95% chi-square band, innovation
        variances) and, when the run carries simulator truth (gt_* columns), per-wheel steady
        slip MAE, body-velocity RMSE and yaw-rate RMSE.

        Example: terrainml estimate runs/sim/run_000.mcap --out runs/est/run_000.parquet --plot runs/est/plots

        Example (real Husky log): terrainml estimate test1.bag --robot husky --topics husky_robot_localization
        --out est.parquet
        """
        from terrainml.estimation.ekf import PRESETS

        if preset not in PRESETS:
            fail(f"--preset must be one of {', '.join(PRESETS)}, got {preset!r}")
        # every output is checked before the (long) estimation, not when it is written
        rep_path = out.with_suffix(".report.json")
        for target in (out, rep_path):
            check_output_writable(target)
        if plot is not None:
            check_output_writable(plot, folder=True)
        rb = open_robot(robot) if robot is not None else None  # None: the spec the run carries
        table = open_run(run, robot=rb, topics=topics)
        from terrainml.estimation.consistency import consistency_report, truth_metrics
        from terrainml.estimation.run import run_robot
        from terrainml.io.damage import damage_summary
        from terrainml.robot import check_wheel_count
        from terrainml.schema import infer_n_wheels, write_run_parquet

        try:
            spec = run_robot(table, rb)
            check_wheel_count(spec, infer_n_wheels(table), run)
        except ValueError as exc:  # RobotSpecError is a ValueError
            fail(str(exc))
        est, diag = _estimate_with_progress(run, table, spec, preset, reference)
        damage = damage_summary(table)
        report = {"run": str(run), "preset": preset, "robot": spec.name, "n_ticks": len(est),
                  "consistency": consistency_report(est, diag), "damage": damage.to_dict()}
        if reference:
            report["filter"] = "reference (terrainml.estimation.reference)"
        if any(c.startswith("gt_") for c in est.columns):
            report["truth"] = truth_metrics(est, spec.n_wheels)
        try:
            write_run_parquet(est, out)
            write_text(rep_path, json.dumps(report, indent=2, default=float))
        except OSError as exc:  # checked above; a full disk or a race can still fail here
            fail(failure_message(out, exc))
        _print_report(report)
        if damage.any:
            console.print(f"[yellow]{run}: {damage.text}[/]")
        if plot is not None:
            from terrainml.estimation.plots import save_plots

            files = save_plots(table, est, diag, spec, plot)
            console.print(f"wrote {len(files)} figures to {plot}")
        console.print(f"wrote {out} ({len(est)} ticks) and {rep_path}")


def _estimate_with_progress(run: Path, table, spec, preset: str, reference: bool):
    """:func:`~terrainml.estimation.run.estimate_run_detailed` with a progress bar (exit 2 on refusal)."""
    from terrainml.estimation.run import estimate_run_detailed

    with Progress(TextColumn("[bold]estimate[/bold] {task.description}"), BarColumn(),
                  TextColumn("{task.percentage:>3.0f}%"), TimeRemainingColumn(),
                  console=console, transient=True) as prog:
        task = prog.add_task(run.name, total=len(table))
        try:
            return estimate_run_detailed(table, spec, preset, progress=lambda k, n: prog.update(task, completed=k),
                                         reference=reference)
        except ValueError as exc:
            fail(f"{run}: {exc}")


def _print_report(report: dict) -> None:
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
