"""train's options: frozen records checked once; candidate model names and window specs parsed once."""

from __future__ import annotations

import dataclasses

import pytest

from terrainml.features.windows import window_spec
from terrainml.pipeline.candidates import SELECT_SPECS, candidate_window_specs, parse_auto_models, parse_models
from terrainml.pipeline.train_options import SelectionOptions, ReplayOptions, TrainOptions


def test_options_are_frozen_and_the_novelty_target_is_checked_once():
    opt = TrainOptions(folds=3, novelty_false_alarm=0.2)
    with pytest.raises(dataclasses.FrozenInstanceError):
        opt.folds = 4  # type: ignore[misc]
    with pytest.raises(ValueError, match=r"\(0, 0.5\)"):
        TrainOptions(novelty_false_alarm=0.7)
    assert dataclasses.replace(opt, open_set=True).novelty_false_alarm == 0.2
    assert ReplayOptions().allow_unproven is False and SelectionOptions().nested is True


def test_candidate_window_specs_parse_auto_names_and_parsed_specs_alike():
    assert [s.name for s in candidate_window_specs("auto")] == list(SELECT_SPECS)
    short = window_spec("short")
    parsed = candidate_window_specs([short, "short,steady"])
    assert parsed[0] is short and [s.name for s in parsed] == ["short", "steady"]
    with pytest.raises(ValueError, match="nope"):
        candidate_window_specs("short,nope")


def test_model_names_parse_as_before():
    assert parse_models("all,svm+hgb") == ["svm", "cnn", "svm+hgb"]
    assert parse_auto_models("auto,cnn") == ["svm", "hgb", "svm+hgb", "cnn"]
    with pytest.raises(ValueError, match="unknown model"):
        parse_models("svm+svm")
