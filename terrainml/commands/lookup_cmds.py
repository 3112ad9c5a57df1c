"""CLI commands of one area (see terrainml.commands)."""

import typer


def register(app: typer.Typer) -> None:
    """Add this area's commands to the top-level app."""
