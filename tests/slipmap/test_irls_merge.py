"""IRLS regressor, sufficient statistics and the exact merge (design §13)."""

import json

import numpy as np
import pytest
import statsmodels.api as sm

from terrainml.slipmap import IRLSRegressor, SlipMap, SlipMapConfig, SlipMapError, merge_maps
from terrainml.slipmap.irls import polynomial_features


def _robot_data(rng, n, outlier_fraction=0.05):
    x = rng.uniform(-8.0, 8.0, size=(n, 2))
    v = 0.1 * x
    y = np.c_[0.05 * v[:, 0] + 0.02 * v[:, 0] ** 3 - 0.1 * (v[:, 1] - v[:, 0]),
              0.05 * v[:, 1] + 0.1 * (v[:, 1] - v[:, 0]),
              -0.1 * np.tanh(v[:, 1] - v[:, 0])]
    y = y + rng.normal(0, 0.01, y.shape)
    bad = rng.random(n) < outlier_fraction
    y[bad] += rng.uniform(-1, 1, (bad.sum(), 3))
    return x, y


def test_merged_estimate_equals_centralised_weighted_fit():
    rng = np.random.default_rng(7)
    cfg = SlipMapConfig(input_scale_radps=8.0)
    data = [_robot_data(rng, n) for n in (300, 450, 200)]
    locals_ = []
    for k, (x, y) in enumerate(data):
        m = SlipMap(cfg, robot_id=f"r{k}").fit_patch("p0", x, y)
        locals_.append(SlipMap.from_json(m.to_json()))  # exchanged as JSON messages
    merged = merge_maps(locals_)
    for j in range(3):
        # centralised weighted fit: every robot's samples with that robot's final IRLS weights
        xs, ys, ws = [], [], []
        for x, y in data:
            reg = IRLSRegressor(input_scale=8.0).fit(x, y[:, j])
            xs.append(polynomial_features(x, 3, 8.0))
            ys.append(y[:, j])
            ws.append(reg.weights_)
        central = sm.WLS(np.concatenate(ys), np.vstack(xs), weights=np.concatenate(ws)).fit().params
        np.testing.assert_allclose(merged.coef("p0")[j], central, rtol=0, atol=1e-9)


def test_irls_beats_ols_with_ten_percent_gross_outliers():
    rng = np.random.default_rng(3)
    n = 600
    x = rng.uniform(-1, 1, size=(n, 2))
    feats = polynomial_features(x, 3, 1.0)
    theta = rng.normal(0, 1, feats.shape[1])
    y = feats @ theta + rng.normal(0, 0.05, n)
    bad = rng.choice(n, n // 10, replace=False)
    y[bad] += rng.uniform(3, 10, bad.size) * rng.choice([-1, 1], bad.size)
    ols, *_ = np.linalg.lstsq(feats, y, rcond=None)
    for norm in ("huber", "bisquare"):
        irls = IRLSRegressor(norm=norm).fit(x, y).coef_
        assert np.linalg.norm(irls - theta) <= np.linalg.norm(ols - theta) / 3, norm
        # the gross outliers are down-weighted
        reg = IRLSRegressor(norm=norm).fit(x, y)
        assert reg.weights_[bad].mean() < 0.5 * np.delete(reg.weights_, bad).mean()


def test_regressor_checks_params_at_fit():
    x = np.random.default_rng(0).normal(size=(50, 2))
    with pytest.raises(ValueError, match="norm"):
        IRLSRegressor(norm="l1").fit(x, x[:, 0])
    with pytest.raises(ValueError, match="degree"):
        IRLSRegressor(degree=0).fit(x, x[:, 0])
    with pytest.raises(ValueError, match="non-finite"):
        IRLSRegressor().fit(x, np.r_[np.nan, x[1:, 0]])


def test_message_round_trip_and_errors(tmp_path):
    rng = np.random.default_rng(1)
    x, y = _robot_data(rng, 200)
    m = SlipMap(SlipMapConfig(input_scale_radps=8.0), "r1").fit_patch("grass", x, y)
    back = SlipMap.from_json(m.to_json())
    np.testing.assert_array_equal(back.coef("grass"), m.coef("grass"))
    msg = json.loads(m.to_json())
    assert msg["schema_version"] == 1 and len(m.to_json()) < 10_000
    msg["schema_version"] = 99
    with pytest.raises(SlipMapError, match="schema_version"):
        SlipMap.from_message(msg)
    other = SlipMap(SlipMapConfig(input_scale_radps=5.0), "r2").fit_patch("grass", x, y)
    with pytest.raises(SlipMapError, match="different settings"):
        merge_maps([m, other])
