"""Study: how the novelty threshold's inner folds set the false alarms it realises.

The threshold of :func:`terrainml.models.novelty.fit_novelty` is the ``1 - target`` quantile of
out-of-fold scores of known windows, scored by scorers fitted in inner grouped folds of the
training runs. An inner scorer sees only ``(m - 1) / m`` of the training runs, so its held-out
windows lie further from its references than a new run lies from the final scorer's (fitted on
every training run): with ``m = 3`` the threshold came out high, and realised 0.3-0.9 % false
alarms for a 3 % target on BorealTC (BENCHMARKS, "Unknown ground").

For each held-out class (the unknown) and outer grouped fold of a windows Parquet, this fits
the model once on the outer training runs (the class left out), then sets the threshold with
each inner-fold scheme (3, 5 and 10 grouped folds, and one run out at a time) on the same
features, and measures on the outer held-out runs:

* realised false alarms: the share of the known held-out *moving* windows flagged (the target
  counts moving windows: the scorer is gated);
* the unknown's moving windows flagged.

The study reads only training runs to set each threshold; the outer held-out runs only measure
it. Run: ``python -m benchmarks.novelty_calibration_study WINDOWS.parquet [--model svm]
[--folds 5] [--targets 0.03,0.05]``; prints a markdown table per scheme (mean over held-out classes,
and per class).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from terrainml.models.novelty import NoveltyScorer, model_features, moving_windows, threshold_splits
from terrainml.pipeline.dataset import read_windows
from terrainml.pipeline.train import _cv_plan, make_factory

SCHEMES = ("3 folds", "5 folds", "10 folds", "one run out")


def _splits(scheme: str, y: np.ndarray, groups: np.ndarray, seed: int) -> list:
    return threshold_splits(y, groups, None if scheme == "one run out" else int(scheme.split()[0]), seed)


def thresholds(F: np.ndarray, y: np.ndarray, groups: np.ndarray, moving: np.ndarray, targets: list[float],
               seed: int) -> dict[tuple[str, float], float]:
    """Threshold of each inner scheme and target: the ``1 - target`` quantile of the out-of-fold
    scores of the moving known windows (as :func:`~terrainml.models.novelty.fit_novelty` sets it)."""
    out = {}
    for scheme in SCHEMES:
        oof = []
        for tr, te in _splits(scheme, y, groups, seed):
            known = np.isin(y[te], np.unique(y[tr])) & moving[te]
            if known.any():
                oof.append(NoveltyScorer().fit(F[tr], y[tr]).score(F[te][known]))
        for t in targets:
            out[scheme, t] = float(np.quantile(np.concatenate(oof), 1.0 - t))
    return out


def study(path: str, model: str, folds: int, targets: list[float], seed: int) -> dict:
    """Per scheme and held-out class: realised false alarms and unknown flagged (moving windows)."""
    ds = read_windows(path)
    plan = _cv_plan(ds, folds, seed, print)
    W = plan.Wcv
    y, groups, moving = W.y, np.asarray(W.groups), moving_windows(W)
    factory = make_factory(model, ds, seed)
    keys = [(s, t) for t in targets for s in SCHEMES]
    res = {key: {} for key in keys}
    for u, name in zip(plan.cv_classes.tolist(), plan.cv_names):
        t0 = time.time()
        counts = {key: np.zeros(4) for key in keys}  # known flagged, known, unknown flagged, unknown
        for tr, te in plan.folds:
            tr = tr[y[tr] != u]
            m = factory()
            m.fit(W.subset(tr), y[tr], groups=groups[tr])
            F_tr, F_te = model_features(m, W.subset(tr)), model_features(m, W.subset(te))
            final = NoveltyScorer().fit(F_tr, y[tr])
            s_te = final.score(F_te)
            known, unk = (y[te] != u) & moving[te], (y[te] == u) & moving[te]
            for key, thr in thresholds(F_tr, y[tr], groups[tr], moving[tr], targets, seed).items():
                flag = s_te > thr
                counts[key] += [flag[known].sum(), known.sum(), flag[unk].sum(), unk.sum()]
        for key in keys:
            c = counts[key]
            res[key][name] = (c[0] / c[1], c[2] / c[3])
        print(f"{name} held out: {time.time() - t0:.0f} s", flush=True)
    return res


def markdown(res: dict) -> str:
    names = list(next(iter(res.values())))
    lines = ["| inner scheme | target % (known moving) | mean false alarms % (moving) | "
             "mean unknown flagged % (moving) | "
             + " | ".join(f"{n} FA / flagged %" for n in names) + " |",
             "|---" * (4 + len(names)) + "|"]
    for (s, t), per in res.items():
        fa, fl = np.mean([v[0] for v in per.values()]), np.mean([v[1] for v in per.values()])
        lines.append(f"| {s} | {100 * t:.0f} | {100 * fa:.2f} | {100 * fl:.1f} | "
                     + " | ".join(f"{100 * v[0]:.2f} / {100 * v[1]:.1f}" for v in per.values()) + " |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("windows")
    ap.add_argument("--model", default="svm")
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--targets", default="0.03,0.05", help="comma-separated false-alarm targets")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    targets = [float(t) for t in a.targets.split(",")]
    print(markdown(study(a.windows, a.model, a.folds, targets, a.seed)))


if __name__ == "__main__":
    main()
