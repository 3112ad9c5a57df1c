"""CLI start-up benchmark: how long ``terrainml --help``, ``terrainml version``, ``terrainml train
--help`` and ``terrainml predict --help`` take as fresh processes. Goal: <= 1 s each.

Each command runs as the console script would (``from terrainml.cli import app; app()``) in a
fresh interpreter with this checkout first on ``PYTHONPATH``. The reference is ``python -c
"import typer"`` (the interpreter plus the CLI library, the floor nothing in terrainml can go
under), timed in the same rounds: on two shared cores the absolute seconds move with the load,
the ratio to the floor much less, and the CPU seconds (user + system of the child, which runs on
one core) hardly at all: on a loaded machine they are the better estimate of the idle wall time.
Commands are interleaved round by round, so a burst of load hits every row alike; each row is the
median of ``repeats`` rounds.

Run: ``.venv/bin/python -m benchmarks.run_all --only bench_cli --out /tmp/b.md``;
``python -m benchmarks.bench_cli --root OTHER_CHECKOUT`` times another checkout (the code before
a change) the same way.
"""

from __future__ import annotations

import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: the console script's body (pyproject ``[project.scripts]``), run with ``python -c``
_ENTRY = "import sys; from terrainml.cli import app; sys.argv[0] = 'terrainml'; sys.exit(app())"
COMMANDS = {
    "terrainml --help": ["--help"],
    "terrainml version": ["version"],
    "terrainml train --help": ["train", "--help"],
    "terrainml predict --help": ["predict", "--help"],
}
REFERENCE = 'python -c "import typer"'
#: a typer app of one command with one option, ``--help``: what any typer CLI pays to parse and
#: render help (typer validates through pydantic, imported at the first parse)
TYPER_APP = "one-option typer app --help"
_TYPER_APP = ("import typer\napp = typer.Typer(add_completion=False)\n@app.command()\n"
              "def main(seed: int = typer.Option(0, help='Seed.')) -> None:\n    pass\napp()\n")
#: before the heavy imports moved into the commands (commit f5507a6), on the same 2-core machine:
#: ``terrainml version`` idle, wall s; and this script with ``--root`` on that checkout (2026-12-07,
#: load 13.8): the four commands' range of CPU s and of the ratio to the floor
OLD_VERSION_IDLE_S = 1.8
OLD_CPU_S = (1.81, 2.09)
OLD_X_FLOOR = (15.1, 16.8)


def _argv(name: str) -> list[str]:
    if name == REFERENCE:
        return [sys.executable, "-c", "import typer"]
    if name == TYPER_APP:
        return [sys.executable, "-c", _TYPER_APP, "--help"]
    return [sys.executable, "-c", _ENTRY, *COMMANDS[name]]


def time_commands(root: Path = ROOT, repeats: int = 5) -> dict[str, tuple[float, float]]:
    """Median wall-clock and CPU seconds of each command (and the references) over ``repeats`` rounds.

    Parameters
    ----------
    root : Path
        Checkout whose ``terrainml`` is timed (first on ``PYTHONPATH``).
    repeats : int
        Rounds; every round runs each command once, in the same order.

    Returns
    -------
    dict
        Command line -> (median wall-clock s, median CPU s: user + system of the child);
        :data:`REFERENCE` and :data:`TYPER_APP` included.
    """
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in (str(root), os.environ.get("PYTHONPATH")) if p))
    names = [REFERENCE, TYPER_APP, *COMMANDS]
    wall: dict[str, list[float]] = {n: [] for n in names}
    cpu: dict[str, list[float]] = {n: [] for n in names}
    for _ in range(repeats):
        for name in names:
            r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
            t0 = time.perf_counter()
            res = subprocess.run(_argv(name), capture_output=True, text=True, env=env, cwd=root)
            wall[name].append(time.perf_counter() - t0)
            r1 = resource.getrusage(resource.RUSAGE_CHILDREN)  # the child is reaped: its usage is in
            cpu[name].append(r1.ru_utime - r0.ru_utime + r1.ru_stime - r0.ru_stime)
            if res.returncode:
                raise RuntimeError(f"{name} failed (exit {res.returncode}): {res.stderr[-2000:]}")
    return {n: (statistics.median(wall[n]), statistics.median(cpu[n])) for n in names}


def _load_1min() -> str:
    try:
        return f"{os.getloadavg()[0]:.1f}"
    except OSError:
        return "n/a"


def run(quick: bool = False, root: Path = ROOT) -> str:
    from benchmarks.bench_ingest import _machine

    repeats = 3 if quick else 5
    load_before = _load_1min()
    med = time_commands(root, repeats)
    ref = med[REFERENCE][0]
    label = {REFERENCE: f"`{REFERENCE}` (floor)", TYPER_APP: f"{TYPER_APP} (any typer CLI)"}
    rows = [f"| {label.get(n, f'`{n}`')} | {w:.2f} | {w / ref:.1f} | {c:.2f} |" for n, (w, c) in med.items()]
    worst = max(med[n][0] for n in COMMANDS)
    worst_cpu = max(med[n][1] for n in COMMANDS)
    return "\n".join([
        "## CLI start-up (`benchmarks/bench_cli.py`)",
        "",
        f"Machine: {_machine()}; 1-minute load {load_before} when it started (other jobs share the "
        f"cores). Each command a fresh process, this checkout first on PYTHONPATH; median of {repeats} "
        "rounds, commands interleaved.",
        "",
        "| command | median wall s | x floor | median CPU s |",
        "|---|---:|---:|---:|",
        *rows,
        "",
        f"Slowest command: {worst:.2f} s wall, {worst_cpu:.2f} s CPU. Goal <= 1 s: "
        f"{'met' if worst <= 1.0 else 'not met'} in wall time under this load, "
        f"{'met' if worst_cpu <= 1.0 else 'NOT met'} in CPU time (on an idle core the wall time is about the "
        f"CPU time: the old `terrainml version` took {OLD_VERSION_IDLE_S:.1f} s idle, {OLD_CPU_S[1]:.1f} s CPU "
        "under load).",
        "",
        f"Before, the same script on the old checkout (`--root`) measured {OLD_CPU_S[0]:.1f}-{OLD_CPU_S[1]:.1f} s "
        f"CPU and {OLD_X_FLOOR[0]:.0f}-{OLD_X_FLOOR[1]:.0f}x the floor for these four commands: the shared "
        "command helpers imported the dataset-spec reader (pandas, scipy, the ingest engine) and the robot "
        "specs for every command. Now no `--help` and no `version` imports "
        "pandas, scipy, sklearn, numba, torch, pyarrow, mcap or cyclonedds (`tests/test_cli_startup.py`); "
        "what is left over the floor is what any typer CLI pays (pydantic, imported by typer at the first "
        "parse, and rich rendering the help; the one-option app's row) plus the command modules and the "
        "longer help of the commands.",
        "",
    ])


if __name__ == "__main__":  # pragma: no cover
    args = sys.argv[1:]
    other = Path(args[args.index("--root") + 1]) if "--root" in args else ROOT
    print(run(quick="--quick" in args, root=other))
