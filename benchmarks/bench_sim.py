"""Simulator speed (goal: >= 100 simulated s per wall s per core) plus the calibration section.

Reference: the same simulator with its kernels run as plain Python (``TERRAINML_NO_NUMBA=1``, in a
subprocess: the physics kernel is a chain of compiled functions, so swapping one ``py_func`` in
would leave the others compiled).
``run(quick)`` returns a Markdown section; the calibration/acceptance figures of
``benchmarks/sim_calibration.py`` are appended.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _physics_rate(terrain, scenario: str, duration_s: float, *, python_kernel: bool = False) -> float:
    """Simulated seconds per wall second of one run (``python_kernel``: plain-Python kernels)."""
    if python_kernel:
        env = dict(os.environ, TERRAINML_NO_NUMBA="1")
        code = ("from benchmarks.bench_sim import _physics_rate; "
                f"print(_physics_rate({terrain!r}, {scenario!r}, {duration_s!r}))")
        out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
        return float(out.stdout.strip().splitlines()[-1])
    import numpy as np

    from terrainml.sim import simulator as simmod
    from terrainml.sim.scenarios import make_scenario

    sc = make_scenario(scenario, terrain, duration_s=duration_s, rng=np.random.default_rng(0))
    sim = simmod.Simulator(sc, seed=0)
    t0 = time.perf_counter()
    sim.run()
    return duration_s / (time.perf_counter() - t0)


def run(quick: bool = False) -> str:
    from terrainml.sim import physics as ph
    from terrainml.sim.generate import simulate
    from terrainml.sim.output import write_mcap, write_parquet

    _physics_rate(0, "straight", 1.0)                       # compile / load the cache
    dur = 30.0 if quick else 120.0
    rows = []
    for terrain, scn in (("pavement", "arc"), ("tilled_loam", "omni"), ("wet_mud", "stop_and_go")):
        ours = _physics_rate(terrain, scn, dur)
        ref = _physics_rate(terrain, scn, 1.0 if quick else 3.0, python_kernel=True)
        rows.append(f"| {scn} on {terrain} | {dur:g} | {ours:.0f} | {ref:.1f} | {ours / ref:.0f}x | "
                    f"{'yes' if ours >= 100 else '**NO**'} |")
    res = simulate("short_grass", "arc", duration_s=30.0, seed=1)
    with tempfile.TemporaryDirectory() as d:
        t0 = time.perf_counter()
        write_mcap(res, Path(d) / "a.mcap")
        t_mcap = time.perf_counter() - t0
        t0 = time.perf_counter()
        write_parquet(res, Path(d) / "a.parquet")
        t_pq = time.perf_counter() - t0
    lines = [
        "## Simulator speed (`benchmarks/bench_sim.py`)", "",
        f"One core, physics + low-level control + truth log (1 kHz physics, 100 Hz control). Compiled kernel: "
        f"numba {'yes' if ph.HAVE_NUMBA else 'NO (pure Python fallback)'}. Reference: the same kernels as plain "
        "Python (`TERRAINML_NO_NUMBA=1`). Target >= 100 simulated s per wall s per core.", "",
        "| run | simulated s | ours (sim s / wall s) | plain Python | ratio | >= 100 |",
        "|---|---|---|---|---|---|", *rows, "",
        f"Output of a 30 s run: MCAP (ROS 2 CDR, ~900 messages/s) {30.0 / t_mcap:.0f} sim s per wall s; "
        f"canonical Parquet table {30.0 / t_pq:.0f} sim s per wall s.", ""]
    from benchmarks.sim_calibration import run as calibration

    return "\n".join(lines) + "\n" + calibration(quick=quick)


if __name__ == "__main__":  # pragma: no cover
    import sys

    print(run(quick="--quick" in sys.argv))
