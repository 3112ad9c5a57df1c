"""terrainml command line (typer + rich). Every command but ``version`` shows an example in its
``--help``: a paragraph of its own, ``Example: terrainml ...`` (or ``Example (what it shows):
terrainml ...``), naming only commands and options the app has (``tests/cli``).

Sub-apps are registered from :data:`terrainml.commands.AREAS`, one module per area. The command
modules and ``demo`` import the heavy parts of the package (simulator, slip maps, models: seconds,
torch comes in through skops) inside their commands, so ``terrainml --help`` stays fast.
"""

from __future__ import annotations

import importlib
import inspect
from pathlib import Path
from typing import Any

import typer
from rich.console import Console
from rich.markup import escape
from typer.core import TyperGroup

from terrainml import __version__
from terrainml.atomic import DISK_ERRNOS, OutputWriteError
from terrainml.commands import AREAS
from terrainml.commands._common import EXIT_USAGE, failure_message


def one_line_paragraphs(text: str | None) -> str | None:
    """``text`` with each paragraph on one line, so the help wraps it to the terminal.

    typer's rich help keeps a docstring's line breaks, which would cut sentences (and examples)
    where the source line ends; a paragraph starting with ``\\b`` is click's verbatim block and
    stays as written.
    """
    if not text:
        return text
    paragraphs = inspect.cleandoc(text).split("\n\n")
    return "\n\n".join(p if p.startswith("\b") else " ".join(line.strip() for line in p.splitlines())
                       for p in paragraphs)


def _reflow_help(command: typer.core.TyperCommand | TyperGroup) -> None:
    """:func:`one_line_paragraphs` on the help of ``command`` and of every command below it."""
    command.help = one_line_paragraphs(command.help)
    for sub in (getattr(command, "commands", None) or {}).values():
        _reflow_help(sub)


class _Group(TyperGroup):
    """The root command group: a write that fails on a full disk (or a quota, a read-only file
    system) in any command is one ``error:`` line naming the output, exit 2, never a traceback.
    Every help text is shown with one line per paragraph (:func:`one_line_paragraphs`)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        _reflow_help(self)

    def invoke(self, ctx: typer.Context) -> Any:
        """Run the command; a failed write becomes the refusal (exit 2), anything else propagates."""
        try:
            return super().invoke(ctx)
        except OSError as exc:
            if not isinstance(exc, OutputWriteError) and exc.errno not in DISK_ERRNOS:
                raise
            Console(stderr=True, soft_wrap=True).print(
                f"[red]error:[/] {escape(failure_message('', exc))}", highlight=False)
            raise typer.Exit(EXIT_USAGE) from None


app = typer.Typer(
    cls=_Group,
    name="terrainml",
    help="Terrain-aware traction for wheeled field robots: ingest logs, estimate slip, "
         "classify terrain, serve desired slip.\n\nQuick start: terrainml demo --out runs/demo",
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

    Example: terrainml demo --out runs/demo
    """
    from terrainml.demo import run_demo  # lazy: importing the whole chain takes seconds

    run_demo(out, seed=seed, console=console)


for _area in AREAS:
    importlib.import_module(f"terrainml.commands.{_area}").register(app)


def main() -> None:  # pragma: no cover - console entry
    app()


if __name__ == "__main__":  # pragma: no cover
    main()
