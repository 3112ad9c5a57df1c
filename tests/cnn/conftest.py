"""Small synthetic raw-window problems with known ground truth for the CNN tests."""

from __future__ import annotations

import numpy as np
import pytest


def make_windows(n_classes: int = 3, n_channels: int = 12, runs_per_class: int = 6,
                 windows_per_run: int = 8, n_timesteps: int = 200, rate_hz: float = 100.0,
                 kind: str = "frequency", seed: int = 0):
    """Windows (n, C, T), labels, run ids; the class is encoded in channel 3 only.

    ``kind="frequency"``: channel 3 carries a sinusoid at ``4 + 6 k`` Hz (class k) with a
    random phase and a per-run amplitude; ``kind="mean"``: channel 3 has mean ``0.8 k``.
    Every other channel is white noise (no class or run information).
    """
    rng = np.random.default_rng(seed)
    t = np.arange(n_timesteps) / rate_hz
    X, y, groups = [], [], []
    run = 0
    for k in range(n_classes):
        for _ in range(runs_per_class):
            amp = rng.uniform(0.7, 1.3)
            offsets = np.zeros((n_channels, 1))
            for _ in range(windows_per_run):
                x = offsets + rng.normal(0.0, 1.0, size=(n_channels, n_timesteps))
                if kind == "frequency":
                    x[3] += 1.5 * amp * np.sin(2 * np.pi * (4 + 6 * k) * t + rng.uniform(0, 2 * np.pi))
                else:
                    x[3] = 0.8 * k + 0.3 * rng.normal(size=n_timesteps)
                X.append(x)
                y.append(k)
                groups.append(f"run{run:03d}")
            run += 1
    return np.asarray(X, np.float32), np.asarray(y), np.asarray(groups)


@pytest.fixture(scope="session")
def freq_data():
    return make_windows(kind="frequency", seed=1, windows_per_run=20)


@pytest.fixture(scope="session")
def fitted(freq_data):
    """A CNN fitted on the first 4 runs of each class (runs 4-5 of each class held out)."""
    from terrainml.models.cnn import CNNClassifier, CNNConfig

    X, y, g = freq_data
    run_no = np.array([int(s[3:]) for s in g])
    train = (run_no % 6) < 4
    clf = CNNClassifier(CNNConfig(max_epochs=30, patience=10), random_state=0, n_threads=1)
    clf.fit(X[train], y[train], g[train])
    return clf, X, y, g, train


@pytest.fixture(scope="session")
def window_factory():
    """The :func:`make_windows` generator (test modules must not import conftest by name)."""
    return make_windows
