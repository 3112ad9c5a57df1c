"""How the selection of ``terrainml train`` scales with the runs and the Dask workers.

Simulated datasets of 1x, 4x and 16x the runs (``terrainml sim generate --runs-per-class 6/24/96
--duration-s 20 --format parquet --seed 0``: 48, 192 and 768 runs of the 8 classes; runs of 20 s
instead of the default 60-120 s, to keep the 16x point within minutes on 2 cores) are cut into
``short`` windows once (``terrainml dataset build``, not timed), then the nested run-grouped
selection of ``train`` (:func:`terrainml.pipeline.autotrain.train_auto` on the windows, as
``terrainml train --data W.parquet --model auto`` runs it: no served replay, no members) runs
with its fits on a ``distributed.LocalCluster`` of 1 and 2 worker processes of one thread each
(:func:`terrainml.pipeline.cluster.dask_jobs`, what ``--dask-address`` opens). Every point runs
in a fresh process and reports:

* wall time of the whole ``train_auto`` (selection, final fit, novelty score, report) and of
  the selection alone;
* fits per second of the selection (fits counted by the selection, over its wall time);
* CPU time of the point (the process and its worker processes): on a shared, loaded machine
  the wall time measures the others' load too, the CPU time does not;
* peak RSS of the point (the process plus its worker processes, sampled every 0.2 s).

With one worker of one thread joblib's Dask backend has one job and runs the fits in the
calling process (sequentially), so the 1-worker point is the one-machine, one-core baseline.
Every point runs with ``OMP_NUM_THREADS=1`` (and the BLAS libraries' equivalents), as Dask's
worker processes do by default, so that N workers use N cores (the boosted trees' OpenMP threads
would otherwise take every core in the 1-worker point, and spin on a loaded machine). The
workers are started without ``MALLOC_TRIM_THRESHOLD_`` (Dask's nanny sets it by default; the
fits then run about 1.6x slower, docs/models.md), unless ``--dask-env``.

``python -m benchmarks.bench_train_scaling [--scales 1,4,16] [--workers 1,2] [--models auto] [--dask-env]``
prints a Markdown table and writes ``runs/bench_train_scaling/results_x1_4_16.json`` (after
``--scales``); the datasets are
cached in ``runs/bench_train_scaling/`` (``--data-dir``).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

OUT = Path("runs") / "bench_train_scaling"
RUNS_PER_CLASS_1X = 6
DURATION_S = 20.0
FOLDS = 5
#: the Dask setting of the workers' glibc trim threshold (unset: ``None``)
WORKER_MALLOC_TRIM = "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_"
#: one thread per process in every point (what Dask's nanny sets in its workers)
ONE_THREAD = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}


def _log(msg: str) -> None:
    print(f"[bench_train_scaling {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def _terrainml(*args: str) -> None:
    subprocess.run([sys.executable, "-m", "terrainml.cli", *args], check=True, stdout=subprocess.DEVNULL)


def dataset(scale: int, data_dir: Path, n_jobs: int) -> Path:
    """The ``short`` windows of the simulated runs at ``scale`` (generated and cut once, cached)."""
    logs, windows = data_dir / f"sim_x{scale}", data_dir / f"sim_x{scale}.parquet"
    if not (logs / "index.csv").exists():
        _log(f"generating {8 * RUNS_PER_CLASS_1X * scale} runs of {DURATION_S:g} s")
        _terrainml("sim", "generate", "--runs-per-class", str(RUNS_PER_CLASS_1X * scale), "--duration-s",
                   str(DURATION_S), "--format", "parquet", "--seed", "0", "--n-jobs", str(n_jobs), "--out", str(logs))
    if not windows.exists():
        _log(f"cutting {logs} into short windows")
        _terrainml("dataset", "build", str(logs), "--windows", "short", "-j", str(n_jobs), "--out", str(windows), "-q")
    return windows


class _PeakRSS:
    """Peak RSS (bytes) of this process and its descendants, sampled every ``period_s``."""

    def __init__(self, period_s: float = 0.2):
        import psutil

        self.proc, self.period_s, self.peak = psutil.Process(os.getpid()), period_s, 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _sample(self) -> None:
        import psutil

        total = 0
        for p in [self.proc, *self.proc.children(recursive=True)]:
            try:
                total += p.memory_info().rss
            except psutil.Error:  # a process that just ended
                pass
        self.peak = max(self.peak, total)

    def _run(self) -> None:
        while not self._stop.is_set():
            self._sample()
            self._stop.wait(self.period_s)

    def __enter__(self) -> "_PeakRSS":
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()
        self._sample()


def point(windows: Path, workers: int, models: str, folds: int, dask_env: bool = False) -> dict:
    """One measurement (run in a fresh process by :func:`main`); ``dask_env``: the workers keep
    Dask's environment (``MALLOC_TRIM_THRESHOLD_`` set), else it is unset as docs/models.md advises."""
    import resource
    import tempfile

    import dask
    from distributed import LocalCluster

    from terrainml.pipeline.autotrain import train_auto
    from terrainml.pipeline.cluster import dask_jobs
    from terrainml.pipeline.dataset import read_windows
    from terrainml.pipeline.candidates import parse_auto_models
    from terrainml.pipeline.train_options import SelectionOptions, TrainOptions

    ds = read_windows(windows)
    if not dask_env:
        dask.config.set({WORKER_MALLOC_TRIM: None})
    with _PeakRSS() as rss, tempfile.TemporaryDirectory() as tmp, \
            LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster:
        with dask_jobs(cluster.scheduler_address):
            t0 = time.perf_counter()
            res = train_auto(None, ds.robot, Path(tmp) / "m", TrainOptions(folds=folds, seed=0),
                             SelectionOptions(models=tuple(parse_auto_models(models)), budget_min=None),
                             datasets={ds.spec.name: ds})
            wall = time.perf_counter() - t0
    use = [resource.getrusage(w) for w in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)]  # workers reaped
    sel = res.selection
    return {"runs": int(len(set(ds.windows.groups.tolist()))), "windows": int(len(ds.windows)), "workers": workers,
            "models": models, "folds": folds, "wall_s": wall, "select_s": sel.timing_s["total_s"],
            "fit_s": sel.timing_s["fit_s"],
            "fits": sel.timing_s["fits"], "fits_per_s": sel.timing_s["fits"] / sel.timing_s["total_s"],
            "cpu_s": sum(u.ru_utime + u.ru_stime for u in use), "peak_rss_mb": rss.peak / 2**20,
            "chosen": sel.chosen.name, "nested_balanced_accuracy": sel.honest["mean"],
            "worker_env": "dask" if dask_env else "no MALLOC_TRIM_THRESHOLD_"}


def markdown(rows: list[dict]) -> str:
    base = next((r for r in rows if r["workers"] == 1 and r["runs"] == min(x["runs"] for x in rows)), rows[0])
    out = ["| runs | windows | workers | wall (s) | x baseline | CPU (s) | selection (s) | fits | fits/s "
           "| peak RSS (MB) | chosen | nested bal. acc. |", "|" + "---|" * 12]
    for r in rows:
        out.append(f"| {r['runs']} | {r['windows']} | {r['workers']} | {r['wall_s']:.0f} | "
                   f"{r['wall_s'] / base['wall_s']:.1f} | {r['cpu_s']:.0f} | {r['select_s']:.0f} | {r['fits']} | "
                   f"{r['fits_per_s']:.2f} | "
                   f"{r['peak_rss_mb']:.0f} | {r['chosen']} | {r['nested_balanced_accuracy']:.3f} |")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scales", default="1,4,16", help="run multiples of 48 runs (comma-separated)")
    ap.add_argument("--workers", default="1,2", help="Dask worker processes per point (comma-separated)")
    ap.add_argument("--models", default="auto", help="the selection's models (train --model)")
    ap.add_argument("--folds", type=int, default=FOLDS)
    ap.add_argument("--dask-env", action="store_true", help="keep Dask's worker environment (MALLOC_TRIM_THRESHOLD_ "
                    "set; the fits run about 1.6x slower)")
    ap.add_argument("--data-dir", type=Path, default=OUT)
    ap.add_argument("-j", "--n-jobs", type=int, default=2, help="jobs for generating and cutting the data")
    ap.add_argument("--point", type=Path, help=argparse.SUPPRESS)  # internal: one point, JSON on stdout
    a = ap.parse_args(argv)
    if a.point is not None:
        print(json.dumps(point(a.point, int(a.workers), a.models, a.folds, a.dask_env)))
        return
    a.data_dir.mkdir(parents=True, exist_ok=True)
    rows = []
    for scale in [int(s) for s in a.scales.split(",")]:
        windows = dataset(scale, a.data_dir, a.n_jobs)
        for w in [int(x) for x in a.workers.split(",")]:
            _log(f"{scale}x runs, {w} worker(s), models {a.models}")
            r = subprocess.run([sys.executable, "-m", "benchmarks.bench_train_scaling", "--point", str(windows),
                                "--workers", str(w), "--models", a.models, "--folds", str(a.folds),
                                *(["--dask-env"] if a.dask_env else [])],
                               check=True, capture_output=True, text=True, env={**os.environ, **ONE_THREAD})
            rows.append({"scale": scale, **json.loads(r.stdout.strip().splitlines()[-1])})
            _log(json.dumps(rows[-1]))
            (a.data_dir / f"results_x{a.scales.replace(',', '_')}.json").write_text(json.dumps(rows, indent=2) + "\n")
    print(markdown(rows))


if __name__ == "__main__":
    main()
