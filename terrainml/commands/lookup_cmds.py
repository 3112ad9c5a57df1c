"""CLI of the lookup area: ``terrainml lookup build|show|plot`` (design §10, §15)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Optional

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from terrainml.commands._common import check_output_writable, console, fail, open_robot
from terrainml.commands._help import listed, robot_help
from terrainml.lookup.catalogue_names import BUILTIN_CATALOGUES

if TYPE_CHECKING:
    from terrainml.robot import RobotSpec

lookup_app = typer.Typer(
    name="lookup",
    help="Desired-slip lookup: class x {traction, braking, steady} targets from terramechanics "
         "and the robot spec, for the simulated classes or any terrain catalogue (design §10)."
         "\n\nExample: terrainml lookup show --json",
    no_args_is_help=True,
    add_completion=False,
)

_CATALOGUE_HELP = (f"Terrain catalogue: a YAML path or a built-in name ({listed(BUILTIN_CATALOGUES)}); "
                   "default the eight simulated classes.")
_CLASSES_HELP = ("Comma-separated class names, in the model's order (default every class of "
                 "the catalogue).")


def _load_table(robot: Optional[RobotSpec], table_path: Optional[Path],
                catalogue: Optional[str] = None, classes: Optional[str] = None):
    """Build a table (for ``robot``, from ``catalogue`` when given) or read ``table_path``.

    ``robot`` is resolved by the command (:func:`open_robot`; None: the reference robot).

    Exits with code 2 and a message naming the file on any refusal.
    """
    from terrainml.lookup.catalogue import CatalogueError
    from terrainml.lookup.table import DesiredSlipTable, LookupTableError

    names = None
    if classes is not None:
        names = [c.strip() for c in classes.split(",") if c.strip()]
        if not names:
            fail(f"--classes: no class name in {classes!r}")
    try:
        if table_path is not None:
            if catalogue is not None or names is not None:
                fail("--table reads a saved table: --catalogue and --classes do not apply")
            return DesiredSlipTable.load(table_path, robot=robot)
        if catalogue is None and names is None:
            return DesiredSlipTable.build(robot)
        return DesiredSlipTable.from_catalogue(catalogue or "reference", robot, class_names=names)
    except (LookupTableError, CatalogueError) as exc:  # the message names the file
        fail(str(exc))


def _rich_table(table) -> None:
    t = Table(title=f"Desired slip, robot '{table.robot_spec.get('name')}' "
                    f"(spec sha256 {table.robot_sha256[:12]})")
    for col, just in (("id", "right"), ("class", "left"), ("traction", "right"),
                      ("braking", "right"), ("steady", "right"), ("kind T/B", "left"),
                      ("notes", "left")):
        t.add_column(col, justify=just)
    for r in table.rows:
        t.add_row(str(r.id), escape(r.name), f"{r.traction:+.3f}", f"{r.braking:+.3f}",
                  f"{r.steady:+.3f}", f"{r.traction_kind}/{r.braking_kind}",
                  "; ".join(r.notes))
    Console().print(t)  # stdout: the table is the command's output


@lookup_app.command("build")
def build(
    out: Path = typer.Option(..., "--out", help="Output JSON file for the table."),
    robot: Optional[str] = typer.Option(None, "--robot", help=robot_help()),
    catalogue: Optional[str] = typer.Option(None, "--catalogue", help=_CATALOGUE_HELP),
    classes: Optional[str] = typer.Option(None, "--classes", help=_CLASSES_HELP),
) -> None:
    """Compute the desired-slip table for a robot (and a class set) and write it as JSON.

    The JSON holds the targets, the class names and parameters (or given targets and their
    sources) they came from, the robot spec and its sha256, and a checksum (verified on load).

    Example: terrainml lookup build --robot husky --out table.json

    Example (BorealTC's classes): terrainml lookup build --catalogue borealtc --robot husky --out table.json
    """
    check_output_writable(out)
    table = _load_table(_robot(robot), None, catalogue, classes)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        table.save(out)
    except OSError as exc:  # checked above; a full disk or a race can still fail here
        fail(f"{out}: cannot write the table ({exc.strerror or exc})")
    _rich_table(table)
    console.print(f"wrote {out}")


@lookup_app.command("show")
def show(
    robot: Optional[str] = typer.Option(None, "--robot", help=robot_help()),
    as_json: bool = typer.Option(False, "--json",
                                 help='Print {"classes": [{"id", "name", "traction", "braking", '
                                      '"steady"}, ...]} instead of a table.'),
    table_path: Optional[Path] = typer.Option(None, "--table",
                                              help="Show a saved table (verified) instead of "
                                                   "building one."),
    catalogue: Optional[str] = typer.Option(None, "--catalogue", help=_CATALOGUE_HELP),
    classes: Optional[str] = typer.Option(None, "--classes", help=_CLASSES_HELP),
) -> None:
    """Print the desired-slip table (rich table, or JSON with --json).

    Example: terrainml lookup show --json

    Example (BorealTC's classes): terrainml lookup show --catalogue borealtc --robot husky
    """
    table = _load_table(_robot(robot), table_path, catalogue, classes)
    if as_json:
        print(json.dumps(table.to_summary()))
    else:
        _rich_table(table)


@lookup_app.command("plot")
def plot(
    out: Path = typer.Option(..., "--out", help="Output PNG file."),
    robot: Optional[str] = typer.Option(None, "--robot", help=robot_help()),
    table_path: Optional[Path] = typer.Option(None, "--table", help="Mark a saved table's "
                                                                    "targets."),
    catalogue: Optional[str] = typer.Option(None, "--catalogue", help=_CATALOGUE_HELP),
    classes: Optional[str] = typer.Option(None, "--classes", help=_CLASSES_HELP),
) -> None:
    """Draw mu_net(s) per class with the chosen targets (like thesis Fig. 8.1).

    Traction (^), braking (v) and steady (o) points are marked on each class's curve.

    Example: terrainml lookup plot --out lookup.png
    """
    from terrainml.lookup.table_plot import plot_table

    check_output_writable(out)
    rb = _robot(robot)
    table = _load_table(rb, table_path, catalogue, classes)
    try:
        path = plot_table(out, robot=rb if rb is not None else _robot_of(table), table=table)
    except OSError as exc:  # checked above; a full disk or a race can still fail here
        fail(f"{out}: cannot write the figure ({exc.strerror or exc})")
    console.print(f"wrote {path}")


def _robot(robot: Optional[str]) -> Optional[RobotSpec]:
    """``--robot`` resolved (exit 2 naming a bad spec); None stays None (the reference robot)."""
    return open_robot(robot) if robot is not None else None


def _robot_of(table):
    from terrainml.robot import RobotSpec

    return RobotSpec.from_dict(table.robot_spec, source="table")


def register(app: typer.Typer) -> None:
    """Add this area's commands to the top-level app."""
    app.add_typer(lookup_app, name="lookup")
