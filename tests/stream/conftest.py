"""Fixtures of the stream tests (fakes and helpers live in ``stream_fakes.py``)."""

from __future__ import annotations

import pytest
from shared_cache import shared_dir
from stream_fakes import CLASS_IDS, FakeClassifier, FakeEstimator, FakeTable, _synthetic_windows

from terrainml.classes import TERRAIN_CLASSES as TERRAIN
from terrainml.robot import load_robot


@pytest.fixture
def robot():
    return load_robot()


@pytest.fixture
def fake_predictor(robot):
    from terrainml.stream.tick.config import ServingConfig
    from terrainml.stream.tick.predictor import Predictor

    def make(classifier=None, estimator=None, window_spec=None, **config):
        return Predictor(robot, FakeTable(), classifier or FakeClassifier(),
                         estimator or FakeEstimator(robot), window_spec=window_spec,
                         config=ServingConfig(**config))

    return make


@pytest.fixture(scope="session")
def model_dir(tmp_path_factory):
    """A tiny verified model folder (SVM on synthetic windows), built with the artifact API once
    for every xdist worker (:func:`shared_cache.shared_dir`)."""
    return shared_dir(tmp_path_factory, "stream-model", _build_tiny_model) / "tiny"


def _build_tiny_model(folder):
    from terrainml.features.sets import FeatureSet
    from terrainml.features.windows import WindowSpec
    from terrainml.lookup.table import DesiredSlipTable
    from terrainml.models.artifacts import TrainingProvenance, save_artifact
    from terrainml.models.svm import SVMClassifier

    robot = load_robot()
    wins = _synthetic_windows(robot)
    clf = SVMClassifier(FeatureSet.for_robot(robot), C_grid=[10.0], gamma_grid=["scale"],
                        inner_folds=2).fit(wins, wins.y)
    out = folder / "tiny"
    save_artifact(out, {"svm": clf}, TrainingProvenance(
                      classes=list(CLASS_IDS), class_names=[TERRAIN[c] for c in CLASS_IDS],
                      channels=list(wins.channels), window_spec=WindowSpec(), robot=robot,
                      training_fingerprint="test"),
                  attachments={"desired_slip_table.json": DesiredSlipTable.build(robot).to_json()})

