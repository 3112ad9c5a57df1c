"""Study: the served novelty score's k-NN search, one window at a time (serving p99).

On the serving benchmark's model (:func:`benchmarks.bench_serving._model`, or ``--model-dir``
of one built that way) and the windows of a held-out stop-and-go course that pass the rules,
each search variant scores every window alone (thread CPU per window, ``--passes`` passes,
median / p90 / p99), and its scores are compared with sklearn's exact k-d tree search (largest
relative difference, windows whose flag differs):

* ``bounded dD``: the served search (:class:`terrainml.models.novelty._BoundedSearch`) with a
  projection of D dimensions (12 is :data:`~terrainml.models.novelty._BOUND_DIMS`);
* ``brute f64``: every reference by one matrix product per class, ``|z|^2 - 2 z.r + |r|^2``
  (the served search until 2026-12-04);
* ``brute f32``: the same in float32 (not exact: its differences are listed);
* ``sklearn brute``: ``NearestNeighbors(algorithm="brute").kneighbors`` per class.

Run: ``python -m benchmarks.novelty_search_study [--model-dir DIR] [--passes 3]``.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from sklearn.neighbors import NearestNeighbors

from benchmarks.bench_serving import EVAL_SEEDS, _course, _model, _ring_snapshots
from terrainml.features.windows import Windows, cut_windows
from terrainml.models.novelty import NoveltyScorer, _BoundedSearch, proba_and_features
from terrainml.stream.tick.ring import is_label


def course_features(model_dir, seed: int = EVAL_SEEDS[0], n: int = 2000) -> tuple[NoveltyScorer, np.ndarray]:
    """The model's scorer and the features (n_windows, F) of the windows of a held-out
    stop-and-go course that pass the rules (ring snapshots of every 7th tick)."""
    pred, snaps = _ring_snapshots(model_dir, _course("course_stop_and_go", seed, 120.0), n)
    clf, rows = pred.classifier, []
    for snap in snaps:
        w, _ = cut_windows(pred.ring.column_view(snap, is_label), clf.robot, spec=clf.window_spec,
                           online=True, with_meta=False)
        if len(w):
            x = Windows(w.X[-1:], w.channels, None, w.rate_hz)
            rows.append(proba_and_features(clf.model, clf.features.transform(x) if clf.features else x)[1])
    return clf.novelty, np.vstack(rows)


def _queries(s: NoveltyScorer, F: np.ndarray) -> np.ndarray:
    """Each window in the scale of each search (each class's for ``class_knn``): (n, K, F)."""
    return np.stack([s._window_queries(z) for z in s._standardise(s._check(F))])


def variants(s: NoveltyScorer) -> dict:
    """name -> function of one window's queries (K, F) returning its score."""
    refs, k = s._reference_sets(), s.k
    r32 = [r.astype(np.float32) for r in refs]
    sq64, sq32 = [(r * r).sum(axis=1) for r in refs], [(r * r).sum(axis=1) for r in r32]

    def brute(Q, R, sq):
        Q = Q.astype(R[0].dtype)
        return float(min(np.sqrt(np.partition(np.maximum((q @ q) - 2.0 * (r @ q) + rs, 0.0), k - 1)[k - 1])
                         for q, r, rs in zip(Q, R, sq)))

    nns = [NearestNeighbors(n_neighbors=k, algorithm="brute").fit(r) for r in refs]
    out = {f"bounded {d}D": _BoundedSearch(refs, k, d).min_kth for d in (8, 12, 16)}
    out["brute f64"] = lambda Q: brute(Q, refs, sq64)
    out["brute f32"] = lambda Q: brute(Q, r32, sq32)
    out["sklearn brute"] = lambda Q: float(min(nn.kneighbors(q[None])[0][0, -1] for nn, q in zip(nns, Q)))
    return out


def exact_scores(s: NoveltyScorer, QQ: np.ndarray) -> np.ndarray:
    """sklearn's exact k-d tree search (distances from the differences), smallest over classes."""
    trees = [NearestNeighbors(n_neighbors=s.k, algorithm="kd_tree").fit(r) for r in s._reference_sets()]
    return np.min([t.kneighbors(QQ[:, j])[0][:, -1] for j, t in enumerate(trees)], axis=0)


def run(model_dir=None, passes: int = 3) -> str:
    with tempfile.TemporaryDirectory() as tmp:
        if model_dir is None:
            model_dir = _model("short", 5, Path(tmp) / "svm")[0]
        s, F = course_features(model_dir)
        QQ = _queries(s, F)
        truth = exact_scores(s, QQ)
        ref_shape = s.reference_.shape
        lines = [f"Novelty search, one window at a time: {len(F)} windows of held-out course "
                 f"course_stop_and_go {EVAL_SEEDS[0]}, {len(s.classes_)} classes, {ref_shape[0]} "
                 f"references x {ref_shape[1]} features, k = {s.k}; thread CPU per window, "
                 f"{passes} passes.", "",
                 "| search | median ms | p90 ms | p99 ms | max relative difference to sklearn's exact "
                 "search | windows flagged differently |", "|---|---|---|---|---|---|"]
        for name, f in variants(s).items():
            scores = np.array([f(Q) for Q in QQ])
            ms = []
            for _ in range(passes):
                for Q in QQ:
                    c0 = time.thread_time_ns()
                    f(Q)
                    ms.append((time.thread_time_ns() - c0) / 1e6)
            rel = float(np.max(np.abs(scores - truth) / np.maximum(truth, 1e-300)))
            flips = int(np.sum((scores > s.threshold) != (truth > s.threshold)))
            lines.append(f"| {name} | {np.median(ms):.3f} | {np.percentile(ms, 90):.3f} | "
                         f"{np.percentile(ms, 99):.3f} | {rel:.1e} | {flips} |")
    return "\n".join(lines)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model-dir", default=None, help="a model built as bench_serving builds it")
    ap.add_argument("--passes", type=int, default=3)
    a = ap.parse_args()
    print(run(a.model_dir, a.passes))
