"""Options of ``terrainml train``, resolved once at the command line into frozen records.

:class:`TrainOptions` says how every model is cross-validated, fitted and given its novelty
score; :class:`ReplayOptions` how the served model is proven on the served path before it is
saved; :class:`SelectionOptions` what the selecting ``train`` chooses among. The command line
builds them once (``terrainml.commands.train_cmd``) and hands them down unchanged to
:func:`terrainml.pipeline.train.train`, :func:`terrainml.pipeline.autotrain.train_auto` and the
sensor members' training.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

from terrainml.models.novelty_target import DEFAULT_FALSE_ALARM, check_false_alarm

__all__ = ["TrainOptions", "ReplayOptions", "SelectionOptions", "DEFAULT_BUDGET_MIN", "REPLAY_SEGMENT_S",
           "MIN_CLASSIFIED_SHARE"]

#: ``--budget-min`` default, minutes
DEFAULT_BUDGET_MIN = 30.0
#: ``--replay-s`` default: seconds of every held-out run replayed (from its middle)
REPLAY_SEGMENT_S = 30.0
#: a model whose replay classifies on fewer of the moving ticks is refused
MIN_CLASSIFIED_SHARE = 0.5


@dataclass(frozen=True)
class TrainOptions:
    """How the models are cross-validated, fitted and given their novelty score.

    Attributes
    ----------
    folds : outer grouped CV folds (by run), >= 2.
    seed : seed of the run partition and of the models.
    n_jobs : joblib jobs over folds.
    novelty_false_alarm : the novelty threshold's target, the share of moving known windows of a
        held-out training run over it, in (0, 0.5) (ValueError otherwise); higher finds more
        unknown ground and serves more known ground the safe cap.
    ablation : also run the SVM feature-set ablation (the single-spec path; off by default: one more
        CV per feature subset).
    open_set : also run the leave-one-class-out evaluation of the served model's novelty score.
    model_params : {kind: {param: value}} constructor overrides (the single-spec path).
    """

    folds: int = 5
    seed: int = 0
    n_jobs: int = 1
    novelty_false_alarm: float = DEFAULT_FALSE_ALARM
    ablation: bool = False
    open_set: bool = False
    model_params: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        check_false_alarm(self.novelty_false_alarm)


@dataclass(frozen=True)
class ReplayOptions:
    """How the served model is proven on the served path and what it serves.

    Attributes
    ----------
    segment_s : s of every held-out run replayed through the online predictor.
    allow_unproven : save a model the replay refuses (the report says so).
    min_classified_share : the refusal threshold, share of moving ticks classified.
    catalogue : terrain catalogue of the desired-slip table (``--catalogue``: YAML path or
        built-in name); None: the built-in one with every class, else class-free serving.
    members : the folder is saved with sensor members, so every fold's model is replayed with the
        members its held-out runs call on, each fitted on the fold's training windows
        (:func:`~terrainml.pipeline.train.fold_model`), as ``predict`` serves the folder. False
        for a folder without members (``--no-members``, ``--sensors``, a member itself).
    """

    segment_s: float = REPLAY_SEGMENT_S
    allow_unproven: bool = False
    min_classified_share: float = MIN_CLASSIFIED_SHARE
    catalogue: str | None = None
    members: bool = False


@dataclass(frozen=True)
class SelectionOptions:
    """What the selecting ``train`` chooses among and how long it may take.

    Attributes
    ----------
    specs : ``"auto"`` (:data:`~terrainml.pipeline.candidates.SELECT_SPECS`) or the candidate window
        specs, parsed (:class:`~terrainml.features.windows.WindowSpec`) or by name.
    models : ``"auto"`` (:data:`~terrainml.pipeline.candidates.AUTO_MODELS`) or the candidate model names.
    budget_min : time budget of the selection, min (None: none); see
        :func:`~terrainml.pipeline.select.select`.
    nested : False for one spec and one model fixed beforehand (a sensor member): its grouped
        K-fold CV, with no inner level.
    preset : estimation preset the candidate windows are cut with.
    sensors : sensor groups the model may use (None: all).
    """

    specs: str | tuple = "auto"
    models: str | tuple = "auto"
    budget_min: float | None = DEFAULT_BUDGET_MIN
    nested: bool = True
    preset: str = "robust"
    sensors: tuple[str, ...] | None = None
