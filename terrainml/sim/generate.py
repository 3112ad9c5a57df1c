"""Generate simulated runs: one run, or a labelled dataset (K runs per class, joblib-parallel).

Per-run seeds come from ``numpy.random.SeedSequence(seed).spawn(n)`` (design §14), so a dataset is
identical whatever ``n_jobs`` is.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
from joblib import Parallel, delayed

from terrainml.atomic import atomic_output
from terrainml.classes import TERRAIN_CLASSES, class_id
from terrainml.sim.output import write_mcap, write_parquet
from terrainml.sim.scenarios import LABELLED_SCENARIOS, make_scenario
from terrainml.sim.simulator import SimResult, Simulator

INDEX_COLUMNS = ("run_id", "file", "terrain", "scenario", "seed", "duration_s")


def simulate(terrain, scenario: str = "straight", *, speed_mps: float = 1.0, duration_s: float = 30.0,
             seed=0, robot=None, spread: float = 0.15, **scenario_kw) -> SimResult:
    """Simulate one run. ``seed``: int or SeedSequence (scenario draws and the run both derive from it)."""
    ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(int(seed))
    ss_scn, ss_sim = ss.spawn(2)
    sc = make_scenario(scenario, terrain, speed_mps=speed_mps, duration_s=duration_s,
                       rng=np.random.default_rng(ss_scn), **scenario_kw)
    res = Simulator(sc, robot, ss_sim, spread=spread).run()
    res.seed = int(seed) if not isinstance(seed, np.random.SeedSequence) else int(ss.entropy)
    return res


def write_run(res: SimResult, path: Path, run_id: str | None = None) -> Path:
    path = Path(path)
    if path.suffix == ".parquet":
        return write_parquet(res, path, run_id)
    return write_mcap(res, path, run_id)


@dataclass(frozen=True)
class RunSpec:
    run_id: str
    terrain: int
    scenario: str
    speed_mps: float
    duration_s: float
    seed_index: int


def dataset_plan(runs_per_class: int, seed: int, duration_s: float | None = None,
                 classes=None) -> tuple[list[RunSpec], list[np.random.SeedSequence]]:
    """Run specs (class, scenario, speed, duration) and per-run seeds for a labelled dataset."""
    classes = [class_id(c) for c in (classes if classes is not None else range(len(TERRAIN_CLASSES)))]
    n = runs_per_class * len(classes)
    seeds = np.random.SeedSequence(int(seed)).spawn(n)
    specs = []
    k = 0
    for c in classes:
        for j in range(runs_per_class):
            rng = np.random.default_rng(seeds[k].spawn(1)[0])
            scenario = LABELLED_SCENARIOS[(j + c) % len(LABELLED_SCENARIOS)]
            dur = float(duration_s) if duration_s is not None else float(np.round(rng.uniform(60.0, 120.0)))
            speed = float(np.round(rng.uniform(0.5, 1.2), 2))
            specs.append(RunSpec(f"sim_{TERRAIN_CLASSES[c]}_{j:03d}", c, scenario, speed, dur, k))
            k += 1
    return specs, seeds


def _one(spec: RunSpec, seed: np.random.SeedSequence, out_dir: Path, fmt: str, robot) -> dict:
    res = simulate(spec.terrain, spec.scenario, speed_mps=spec.speed_mps, duration_s=spec.duration_s,
                   seed=seed, robot=robot)
    path = out_dir / f"{spec.run_id}.{fmt}"
    write_run(res, path, spec.run_id)
    return {"run_id": spec.run_id, "file": path.name, "terrain": TERRAIN_CLASSES[spec.terrain],
            "scenario": spec.scenario, "seed": f"{seed.entropy}:{'/'.join(map(str, seed.spawn_key))}",
            "duration_s": f"{spec.duration_s:g}"}


def generate_dataset(out_dir: str | Path, runs_per_class: int, seed: int = 0, *, n_jobs: int = 1,
                     duration_s: float | None = None, fmt: str = "mcap", robot=None,
                     progress: Callable[[int, int], None] | None = None) -> Path:
    """Write ``runs_per_class`` runs of every class to ``out_dir`` plus ``index.csv``; return the index path.

    ``fmt``: ``mcap`` (ROS 2 logs) or ``parquet`` (canonical run tables, faster).
    """
    if fmt not in ("mcap", "parquet"):
        raise ValueError(f"format must be mcap or parquet, got {fmt!r}")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    specs, seeds = dataset_plan(runs_per_class, seed, duration_s)
    rows: list[dict] = []
    total = len(specs)
    gen = Parallel(n_jobs=n_jobs, return_as="generator")(
        delayed(_one)(s, seeds[s.seed_index], out_dir, fmt, robot) for s in specs)
    for row in gen:
        rows.append(row)
        if progress is not None:
            progress(len(rows), total)
    index = out_dir / "index.csv"
    with atomic_output(index) as tmp, tmp.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=INDEX_COLUMNS)
        w.writeheader()
        for r in rows:
            w.writerow(r)
    return index
