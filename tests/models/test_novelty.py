"""Novelty score: far windows score above near ones, the inner-fold threshold flags about the
target share of fresh known windows (drawn from the same Gaussians), and the saved scorer is
refused when its file or its manifest entry disagree."""

from __future__ import annotations

import numpy as np
import pytest

from terrainml.models.novelty import NoveltyError, NoveltyScorer, fit_novelty


def _clusters(rng, n_per_run=40, runs=4):
    """Two known classes: unit Gaussians at -3 and +3 on axis 0, in 6 dimensions, several runs."""
    F, y, g = [], [], []
    for c, mu in enumerate((-3.0, 3.0)):
        for r in range(runs):
            x = rng.normal(size=(n_per_run, 6))
            x[:, 0] += mu
            F.append(x)
            y += [c] * n_per_run
            g += [f"c{c}r{r}"] * n_per_run
    return np.vstack(F), np.asarray(y), np.asarray(g)


@pytest.mark.parametrize("method", ["class_knn", "knn", "mahalanobis"])
def test_far_windows_score_above_known_ones_and_threshold_meets_target(method):
    rng = np.random.default_rng(0)
    F, y, g = _clusters(rng)
    scorer, info = fit_novelty(F, y, g, method=method, k=5, false_alarm=0.05, inner_folds=4, seed=0)
    fresh, _, _ = _clusters(np.random.default_rng(1))
    far = rng.normal(size=(200, 6))
    far[:, 1] += 8.0  # 8 sd away along an axis no class varies on
    assert scorer.score(far).min() > np.quantile(scorer.score(fresh), 0.99)
    flagged = scorer.is_unknown(fresh).mean()
    assert flagged <= 0.10  # target 5 %; the final scorer has more references than the inner ones
    assert scorer.is_unknown(far).all()
    assert info["false_alarm_target"] == 0.05


def test_saved_scorer_scores_alike_and_mismatched_entry_is_refused(tmp_path):
    rng = np.random.default_rng(2)
    F, y, g = _clusters(rng)
    scorer, _ = fit_novelty(F, y, g, k=3, seed=0)
    path = scorer.save(tmp_path)
    cfg = scorer.config()
    back = NoveltyScorer.load(path, cfg)
    np.testing.assert_array_equal(back.score(F[:50]), scorer.score(F[:50]))
    with pytest.raises(NoveltyError, match="shapes"):
        NoveltyScorer.load(path, {**cfg, "n_features": 5})
    with pytest.raises(NoveltyError, match="classes"):
        NoveltyScorer.load(path, {**cfg, "classes": [0, 7]})
    path.write_bytes(b"not safetensors")
    with pytest.raises(NoveltyError, match=str(path)):
        NoveltyScorer.load(path, cfg)


@pytest.mark.parametrize("method", ["class_knn", "knn"])
def test_one_window_is_scored_as_in_a_batch_the_k_th_neighbour_by_brute_force(method):
    """Serving scores one window at a time (numpy search); a batch goes through sklearn's index:
    the same k-th neighbour distance, and for ``knn`` the one computed here by hand."""
    rng = np.random.default_rng(3)
    F, y, g = _clusters(rng)
    scorer = NoveltyScorer(method, k=5).fit(F, y)
    Q = rng.normal(size=(100, 6)) * 2.0
    batch = scorer.score(Q)
    one = np.array([scorer.score(Q[i:i + 1])[0] for i in range(len(Q))])
    assert np.allclose(one, batch, rtol=0, atol=1e-9)
    if method == "knn":
        Z = np.clip((Q - F.mean(0)) / F.std(0), -20, 20)
        R = (F - F.mean(0)) / F.std(0)
        d = np.sort(np.linalg.norm(Z[:, None] - R[None], axis=2), axis=1)[:, 4]
        assert np.allclose(one, d, atol=1e-9)
