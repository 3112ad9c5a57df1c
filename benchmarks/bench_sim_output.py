"""`sim generate` to MCAP speed (goal: >= 100 simulated s per wall s on one core.

Measured as a ratio against physics alone in the same run, so the figure travels between machines:
for each run the simulation (:func:`terrainml.sim.generate.simulate`) and the MCAP writing
(:func:`terrainml.sim.output.write_mcap`, messages encoded in blocks) are timed separately, each the
best of a few repeats. ``generate`` is their sum, what ``terrainml sim generate --out RUN.mcap`` does.
Times are the process's CPU time (``time.process_time``: the work is single-threaded, so this is one
core's time, and other jobs sharing the cores do not inflate it); wall-clock rates are given beside.
The canonical Parquet table is timed for comparison. ``run(quick)`` returns a Markdown section.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

RUNS = (("pavement", "arc"), ("tilled_loam", "omni"), ("wet_mud", "stop_and_go"))
TARGET = 100.0      # simulated s per wall s, generate to MCAP


def _best(fn, repeats: int) -> tuple[float, float, object]:
    """Shortest CPU and wall times of ``repeats`` calls of ``fn``, and the last result."""
    cpu, wall, out = float("inf"), float("inf"), None
    for _ in range(repeats):
        c0, w0 = time.process_time(), time.perf_counter()
        out = fn()
        cpu, wall = min(cpu, time.process_time() - c0), min(wall, time.perf_counter() - w0)
    return cpu, wall, out


def measure(terrain: str, scenario: str, duration_s: float, repeats: int = 3) -> dict[str, float]:
    """CPU (and ``*_wall``) seconds of the physics, the MCAP writing and the Parquet writing of one run."""
    from terrainml.sim.generate import simulate
    from terrainml.sim.output import write_mcap, write_parquet

    m: dict[str, float] = {}
    m["physics_s"], m["physics_wall"], res = _best(
        lambda: simulate(terrain, scenario, duration_s=duration_s, seed=1), repeats)
    with tempfile.TemporaryDirectory() as d:
        m["mcap_s"], m["mcap_wall"], _ = _best(lambda: write_mcap(res, Path(d) / "run.mcap"), repeats)
        m["mcap_bytes"] = (Path(d) / "run.mcap").stat().st_size
        m["parquet_s"], _, _ = _best(lambda: write_parquet(res, Path(d) / "run.parquet"), repeats)
    return m


def run(quick: bool = False) -> str:
    from terrainml.sim.generate import simulate
    from terrainml.sim.output import write_mcap

    dur = 20.0 if quick else 60.0
    repeats = 2 if quick else 3
    with tempfile.TemporaryDirectory() as d:            # compile / load the kernels, import the writers
        write_mcap(simulate("pavement", "arc", duration_s=1.0, seed=0), Path(d) / "warm.mcap")
    rows, worst = [], float("inf")
    for terrain, scenario in RUNS:
        m = measure(terrain, scenario, dur, repeats)
        gen_s = m["physics_s"] + m["mcap_s"]
        rate = dur / gen_s
        worst = min(worst, rate)
        rows.append(f"| {scenario} on {terrain} | {dur:g} | {dur / m['physics_s']:.0f} | {dur / m['mcap_s']:.0f} | "
                    f"**{rate:.0f}** | {m['physics_s'] / gen_s:.2f} | "
                    f"{dur / (m['physics_wall'] + m['mcap_wall']):.0f} | {dur / m['parquet_s']:.0f} | "
                    f"{m['mcap_bytes'] / dur / 1e3:.0f} | {'yes' if rate >= TARGET else '**NO**'} |")
    return "\n".join([
        "## `sim generate` to MCAP (`benchmarks/bench_sim_output.py`)", "",
        "One core. Rates in simulated s per CPU s (best of "
        f"{repeats}; *generate, wall*: per wall-clock s). *generate* = physics + MCAP writing (ROS 2 CDR, "
        "~900 messages per simulated s, encoded in blocks of 2 s per topic, one zstd chunk per block); "
        "*share* = physics time / generate time, "
        "the ratio against physics alone measured in the same run. Target: generate >= "
        f"{TARGET:.0f}.", "",
        "| run | simulated s | physics | MCAP writing | generate | share | generate, wall | Parquet writing | "
        "MCAP kB per sim s | >= 100 |",
        "|---|---|---|---|---|---|---|---|---|---|", *rows, "",
        f"Slowest generate: {worst:.0f} simulated s per CPU s.", ""])


if __name__ == "__main__":  # pragma: no cover
    import sys

    print(run(quick="--quick" in sys.argv))
