"""Novelty score: far windows score above near ones, the inner-fold threshold flags about the
target share of fresh known windows (drawn from the same Gaussians), and the saved scorer is
refused when its file or its manifest entry disagree."""

from __future__ import annotations

import numpy as np
import pytest

from terrainml.evaluation.open_set import flagged_at_false_alarm
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
    scorer, info = fit_novelty(F, y, g, method=method, k=5, novelty_false_alarm=0.05, inner_folds=4, seed=0)
    fresh, _, _ = _clusters(np.random.default_rng(1))
    far = rng.normal(size=(200, 6))
    far[:, 1] += 8.0  # 8 sd away along an axis no class varies on
    assert scorer.score(far).min() > np.quantile(scorer.score(fresh), 0.99)
    flagged = scorer.flag(scorer.score(fresh)).mean()
    assert flagged <= 0.10  # target 5 %; the final scorer has more references than the inner ones
    assert scorer.flag(scorer.score(far)).all()
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


def _hard_reference_case(rng, n_features):
    """Classes of unequal sizes (the served search pads the shorter ones), heavy-tailed features,
    one feature constant within a class (its class scale is the 1e-3 floor), duplicate windows
    (tied neighbours), and two classes around the same centre, one of full rank (loose projected
    bounds: often searched first) and one of rank 2 (tight bounds: often the nearest); queries:
    training windows themselves (distance 0), near ones, ones near both overlapping classes, far
    ones (every class far, the search's worst case) and ones beyond the +-20 sd clip."""
    sizes = (12, 150, 600, 40, 1500)
    F, y = [], []
    for c, n in enumerate(sizes):
        x = rng.standard_t(1.5, size=(n, n_features)) + 4.0 * rng.normal(size=n_features)
        if c == 2:
            x[:, 1] = 0.5
        if c == 4:
            x[500:520] = x[:20]
        F.append(x)
        y += [c] * n
    F.append(rng.normal(size=(300, n_features)))
    F.append(rng.normal(size=(300, 2)) @ rng.normal(size=(2, n_features)) + 0.01 * rng.normal(size=(300, n_features)))
    y += [5] * 300 + [6] * 300
    F, y = np.vstack(F), np.asarray(y)
    Q = np.vstack([F[rng.choice(len(F), 15)], F[rng.choice(len(F), 15)] + 0.05 * rng.normal(size=(15, n_features)),
                   F[-300:][rng.choice(300, 10)] + 0.3 * rng.normal(size=(10, n_features)),
                   rng.normal(size=(5, n_features)), rng.normal(size=(10, n_features)) * 30.0,
                   np.full((4, n_features), 1e6)])
    return F, y, Q


def _exact_reference(F, y, Q, method, k):
    """The score written out here with sklearn's exact k-d tree search (distances from the
    differences, as the served search computes them) as the neighbour search."""
    from sklearn.neighbors import NearestNeighbors

    center, sd = F.mean(0), F.std(0)
    scale = np.where(sd > 1e-12, sd, 1.0)
    Z, Zq = ((np.clip((A - center) / scale, -20, 20)) for A in (F, Q))
    if method == "knn":
        return NearestNeighbors(n_neighbors=k, algorithm="kd_tree").fit(Z).kneighbors(Zq)[0][:, -1]
    out = np.full(len(Q), np.inf)
    for c in np.unique(y):
        cc, cs = Z[y == c].mean(0), np.maximum(Z[y == c].std(0), 1e-3)
        nn = NearestNeighbors(n_neighbors=k, algorithm="kd_tree").fit((Z[y == c] - cc) / cs)
        out = np.minimum(out, nn.kneighbors((Zq - cc) / cs)[0][:, -1])
    return out


@pytest.mark.parametrize("method,n_features,k", [("class_knn", 6, 5), ("class_knn", 40, 1),
                                                 ("class_knn", 40, 5), ("knn", 40, 3)])
def test_served_scores_are_an_exact_k_nearest_neighbour_search(method, n_features, k):
    """The served search (a few windows: bounded by projections, branch and bound) returns the
    k-th neighbour distance of an exact search, on data made to stress its bounds."""
    F, y, Q = _hard_reference_case(np.random.default_rng(7), n_features)
    scorer = NoveltyScorer(method, k=k).fit(F, y).prepare_serving()
    truth = _exact_reference(F, y, Q, method, k)
    one = np.array([scorer.score(Q[i:i + 1])[0] for i in range(len(Q))])
    assert np.allclose(one, truth, rtol=1e-12, atol=1e-12)
    assert np.allclose(scorer.score(Q), truth, rtol=1e-12, atol=1e-12)  # 59 windows: the same search
    if k == 1:  # a training window is its own nearest neighbour, at distance 0 exactly
        assert (one[:15] == 0.0).all()


def test_prepare_serving_needs_a_fitted_scorer():
    with pytest.raises(NoveltyError, match="not fitted"):
        NoveltyScorer().prepare_serving()


def test_reach_is_the_unknown_share_over_the_threshold_that_flags_the_false_alarm_share():
    """Hand-worked: known scores 0..99, 5 % false alarms -> threshold 94 (95..99 above it, 5 of 100)."""
    known = np.arange(100.0)
    assert flagged_at_false_alarm(known, np.array([93.5, 94.0, 94.5, 200.0]), 0.05) == 0.5
    assert flagged_at_false_alarm(known, np.array([10.0]), 0.05) == 0.0
    # ties at the threshold are not flagged: a flag is strictly above it
    assert flagged_at_false_alarm(np.ones(100), np.array([1.0, 2.0]), 0.05) == 0.5
    assert np.isnan(flagged_at_false_alarm(known, np.array([]), 0.05))


def test_moving_gate_sets_the_threshold_on_moving_windows_and_never_flags_standing_still(tmp_path):
    """Standing-still windows (a third of each run, moved 6 sd off along an axis) are judged by no
    one: with the gate the threshold is the moving windows' own (about the target share of new
    moving known windows flagged), and a standing-still window is never flagged."""
    rng = np.random.default_rng(4)
    F, y, g = _clusters(rng, n_per_run=60)
    still = np.arange(len(y)) % 3 == 0
    F[still, 2] += 6.0
    ungated, _ = fit_novelty(F, y, g, k=5, novelty_false_alarm=0.05, inner_folds=4, seed=0)
    gated, _ = fit_novelty(F, y, g, moving=~still, k=5, novelty_false_alarm=0.05, inner_folds=4, seed=0)
    assert ungated.moving_mps is None and gated.moving_mps is not None
    fresh, _, _ = _clusters(np.random.default_rng(5), n_per_run=60)  # new runs, all moving
    moving = np.ones(len(fresh), dtype=bool)
    # over all windows the far standing-still ones set the line: almost no moving window reaches it
    assert gated.threshold < ungated.threshold
    assert gated.flag(gated.score(fresh), moving).mean() <= 0.10
    shifted = fresh + np.array([0.0, 2.5, 0, 0, 0, 0])  # new ground: 2.5 sd off on an axis no class varies on
    assert gated.flag(gated.score(shifted), moving).mean() > ungated.flag(ungated.score(shifted)).mean()
    assert not gated.flag(gated.score(shifted), ~moving).any()
    with pytest.raises(NoveltyError, match="moving"):
        gated.flag(gated.score(shifted))
    back = NoveltyScorer.load(gated.save(tmp_path), gated.config())
    assert back.moving_mps == gated.moving_mps


def _runs(rng, n_runs=8, n_per_run=50, dim=6, run_sd=0.6):
    """Three known classes 4 sd apart, each run drawn around its class with its own offset (sd
    ``run_sd`` per axis): a new run of known ground lies a little off every training run."""
    F, y, g = [], [], []
    for c in range(3):
        for r in range(n_runs):
            x = rng.normal(size=(n_per_run, dim)) + rng.normal(scale=run_sd, size=dim)
            x[:, c] += 4.0
            F.append(x)
            y += [c] * n_per_run
            g += [f"c{c}r{r}"] * n_per_run
    return np.vstack(F), np.asarray(y), np.asarray(g)


def test_one_run_out_threshold_realises_its_target_on_new_runs():
    """The default threshold (one training run out at a time) flags about the target share of
    windows of new runs drawn from the same classes (ground truth: the generator); three inner
    folds, whose scorers saw two thirds of the runs, set it too high (fewer flagged)."""
    realised = {3: [], None: []}
    for seed in range(4):
        F, y, g = _runs(np.random.default_rng(seed))
        fresh, _, _ = _runs(np.random.default_rng(100 + seed), n_runs=40)
        for folds in realised:
            scorer, info = fit_novelty(F, y, g, novelty_false_alarm=0.05, inner_folds=folds, seed=0)
            realised[folds].append(scorer.flag(scorer.score(fresh)).mean())
        assert info["inner_folds"] == 24  # one run out: as many folds as training runs
    assert 0.03 <= np.mean(realised[None]) <= 0.07
    assert abs(np.mean(realised[None]) - 0.05) < abs(np.mean(realised[3]) - 0.05)
