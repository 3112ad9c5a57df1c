"""Simulated datasets from recipes (``datasets/*.yaml``): generate, build, cache.

* :func:`load_recipe` reads a recipe (a YAML path or a name in ``datasets/``).
* :func:`simulated_dataset` generates a recipe's simulated logs
  (:func:`terrainml.sim.generate.generate_dataset`), build the windows
  (:func:`terrainml.pipeline.dataset.build_dataset`) and cache the result. The logs are keyed by
  the recipe and a hash of the simulator, lookup and io sources (what writes them); the windows
  file additionally by the estimation and feature sources, so a change there rebuilds only the
  windows. Cache folder: ``$TERRAINML_CACHE`` or ``~/.cache/terrainml``.

This lives in ``experiments`` (not ``features`` or ``sim``) because it drives both the simulator
and the dataset pipeline: nothing in the io -> estimation -> features -> models chain imports it.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

from terrainml._yaml_checks import read_yaml_file
from terrainml.features.windows import WindowSpec
from terrainml.pipeline.dataset import build_dataset, dataset_robot, read_windows, write_windows
from terrainml.sim.generate import generate_dataset

__all__ = ["load_recipe", "simulated_dataset", "RECIPES_DIR"]

RECIPES_DIR = Path(__file__).resolve().parents[2] / "datasets"
_BUILTIN = {
    "sim_default": {"name": "sim_default", "robot": "agrimaro", "runs_per_class": 12, "seed": 0,
                    "duration_s": None, "format": "mcap", "preset": "robust",
                    "window": {"window_s": 2.0, "hop_s": 2.0}},
    "sim_eval_seed1": {"name": "sim_eval_seed1", "robot": "agrimaro", "runs_per_class": 4, "seed": 1,
                       "duration_s": None, "format": "mcap", "preset": "robust",
                       "window": {"window_s": 2.0, "hop_s": 2.0}},
}


def load_recipe(recipe: str | Path = "sim_default") -> dict:
    """A dataset recipe: a YAML path, or a name in ``datasets/`` (built-in copy as fallback)."""
    p = Path(recipe)
    if p.suffix not in (".yaml", ".yml"):
        p = RECIPES_DIR / f"{recipe}.yaml"
    if p.is_file():
        doc = read_yaml_file(p, ValueError, f"{p}: dataset recipe not found")
        if not isinstance(doc, dict):
            raise ValueError(f"{p}: a dataset recipe must be a mapping")
        return doc
    if str(recipe) in _BUILTIN:
        return dict(_BUILTIN[str(recipe)])
    raise ValueError(f"dataset recipe {recipe!r} not found (looked for {p})")


def _code_hash(subs: tuple[str, ...] = ("sim", "io", "estimation", "features", "lookup")) -> str:
    """Hash of the sources under ``terrainml/<sub>`` plus schema.py and robot.py."""
    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha256()
    for sub in subs:
        for f in sorted((root / sub).rglob("*.py")):
            h.update(f.name.encode())
            h.update(f.read_bytes())
    for f in ("schema.py", "robot.py"):
        h.update((root / f).read_bytes())
    return h.hexdigest()[:16]


def simulated_dataset(recipe: str | Path | dict = "sim_default", *, runs_per_class: int | None = None,
                      seed: int | None = None, duration_s: float | None = None, fmt: str | None = None,
                      n_jobs: int = 2, cache_dir: str | Path | None = None, progress=None) -> Any:
    """Generate (or reuse) a recipe's simulated logs and windows.

    Parameters
    ----------
    recipe : name, YAML path or dict (see ``datasets/sim_default.yaml``).
    runs_per_class, seed, duration_s, fmt : override the recipe's values.
    n_jobs : joblib jobs for simulation and building.
    cache_dir : cache root (default ``$TERRAINML_CACHE`` or ``~/.cache/terrainml``).
    progress : optional callback ``(stage, done, total)``.

    Returns
    -------
    terrainml.pipeline.dataset.Dataset
    """
    r = dict(recipe) if isinstance(recipe, dict) else load_recipe(recipe)
    for k, v in (("runs_per_class", runs_per_class), ("seed", seed), ("duration_s", duration_s), ("format", fmt)):
        if v is not None:
            r[k] = v
    spec = WindowSpec(**r.get("window", {}))
    key_doc = {k: r.get(k) for k in ("robot", "runs_per_class", "seed", "duration_s", "format", "preset")}
    key_doc["window"] = spec.to_dict()
    recipe_key = hashlib.sha256(json.dumps(key_doc, sort_keys=True).encode()).hexdigest()[:12]
    root = Path(cache_dir or os.environ.get("TERRAINML_CACHE") or Path.home() / ".cache" / "terrainml")
    # the logs depend on the simulator (and what it writes through); the windows on the whole chain
    folder = root / f"{r.get('name', 'sim')}_{recipe_key}_{_code_hash(('sim', 'lookup', 'io'))}"
    windows_path = folder / f"windows_{_code_hash()}.parquet"
    if windows_path.is_file():
        return read_windows(windows_path)
    logs = folder / "logs"
    robot = dataset_robot(r.get("robot"))  # the recipe's robot, resolved once for both steps
    if not (logs / "index.csv").is_file():
        generate_dataset(logs, int(r["runs_per_class"]), int(r["seed"]), n_jobs=n_jobs,
                         duration_s=r.get("duration_s"), fmt=r.get("format", "mcap"), robot=robot,
                         progress=(lambda d, t: progress("simulate", d, t)) if progress else None)
    ds = build_dataset(logs, robot, r.get("preset", "robust"), spec, n_jobs=n_jobs,
                       progress=(lambda d, t, n: progress("build", d, t)) if progress else None)
    write_windows(ds, windows_path)
    return ds
