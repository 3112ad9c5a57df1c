"""Serving settings of the online predictor, resolved once at the edge (design §10-11).

:class:`ServingConfig` groups the predictor's settings that do not come with the model (the
model brings the robot, the table, the classifier, the window spec, the class names and the
sensor groups): the CLI (``terrainml predict``) and the controllers build one and hand it down.
"""

from __future__ import annotations

from dataclasses import dataclass
from terrainml.stream.tick.clock import MAX_GAP_S, REANCHOR_AFTER
from terrainml.stream.tick.fusion import STALE_M, FusionConfig
from terrainml.stream.tick.health import SILENT_S
from terrainml.stream.tick.policy import SERVE_P

__all__ = ["ServingConfig"]


@dataclass(frozen=True)
class ServingConfig:
    """How the predictor serves (every field has the default ``terrainml predict`` documents).

    Attributes
    ----------
    preset : EKF preset, or None: the model's (``"robust"`` without a model).
    stale_m : m (3.0). More than this travelled since the last classification →
        ``stale_classification`` fallback. The age counts distance (the EKF's body speed
        integrated over ticks), not time: a robot standing still keeps its class.
    serve_p : fused posterior below this → ``uncertain_classification`` fallback (0.6).
    max_age_s : s or None (default: off). An optional wall-time limit on the age of the last
        classification, on top of ``stale_m``.
    fusion : :class:`~terrainml.stream.tick.fusion.FusionConfig`, the terrain filter's settings
        (default: the filter's, with ``confirm_windows`` and ``unknown_windows`` from the model's
        hop and window length and ``settle_m`` :data:`~terrainml.stream.tick.fusion.SETTLE_M`).
    silent_s : s (0.2), health rule: a sensor group silent this long is unhealthy.
    classify_lag_ticks : 0 (default) classifies inline on the hop tick. L > 0 runs the
        classification in a background thread and applies its result exactly L ticks later
        (deterministic: the tick waits for it if needed; :mod:`terrainml.stream.tick.scheduler`).
    max_clock_gap_s : s, > 0 (1.0). Largest step between consecutive ticks of one timeline; a
        larger step either way is a clock jump (:mod:`terrainml.stream.tick.clock`).
    reanchor_after : int >= 1 (5). Consecutive consistent off-timeline samples (K) that
        re-anchor the stream on a new timeline (estimator, health, window buffer and
        classification restart).
    warn_after_m : m (5.0). Once the robot has travelled more than this on healthy ticks with
        no classification while the window rules reject its windows, the ticks fall back with
        ``windows_rejected`` (the message's ``fallback_detail`` names the rule, and for
        ``channel_valid`` the channels) and a warning on stderr says the same.
    open_set : True (default): the model's novelty score (if it has one) flags windows unlike its
        training windows, and ground that keeps being flagged is served as ``unknown_terrain``
       . False: the score is not used, every window is served as one of the model's
        classes (closed-set serving; ``predict --closed-set``).
    """

    preset: str | None = None
    stale_m: float = STALE_M
    serve_p: float = SERVE_P
    max_age_s: float | None = None
    fusion: FusionConfig = FusionConfig()
    silent_s: float = SILENT_S
    classify_lag_ticks: int = 0
    max_clock_gap_s: float = MAX_GAP_S
    reanchor_after: int = REANCHOR_AFTER
    warn_after_m: float = 5.0
    open_set: bool = True
