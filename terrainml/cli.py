"""terrainml command line (typer + rich). Every command has ``--help`` with an example.

Sub-apps are registered by their modules' owners below; each import is local to its command so
``terrainml --help`` stays fast.
"""

from __future__ import annotations

from pathlib import Path

import typer
from rich.console import Console

from terrainml import __version__

app = typer.Typer(
    name="terrainml",
    help="Terrain-aware traction for wheeled field robots: ingest logs, estimate slip, "
         "classify terrain, serve desired slip.\n\nQuick start: `terrainml demo --out runs/demo`.",
    no_args_is_help=True,
    add_completion=False,
)
console = Console(stderr=True, soft_wrap=True)


@app.command()
def version() -> None:
    """Print the terrainml version."""
    print(__version__)


@app.command()
def demo(out: Path = typer.Option(Path("runs/demo"), help="Output folder for the demo's files."),
         seed: int = typer.Option(0, help="Seed for everything random in the demo.")) -> None:
    """Run the whole chain on the embedded default (simulated reference robot).

    Example: ``terrainml demo --out runs/demo``
    """
    from terrainml.demo import run_demo

    run_demo(out, seed=seed, console=console)


def _register_areas() -> None:
    import importlib

    from terrainml.commands import AREAS

    for area in AREAS:
        importlib.import_module(f"terrainml.commands.{area}").register(app)


_register_areas()


def main() -> None:  # pragma: no cover - console entry
    app()


if __name__ == "__main__":  # pragma: no cover
    main()
