"""Serving decision of one tick: a thin layer over :mod:`terrainml.lookup.policy` (SYSTEM §10).

The lookup package owns the policy (confident / uncertain / fallback) and the per-wheel sign
logic of eq. 8.7-8.9. The predictor adds the two reasons only it can know: ``clock_jump`` (the
tick's time stamp is off the stream's timeline, :mod:`terrainml.stream.clock`, so the chain did
not run on it) and ``classifier_error`` (the last classification attempt raised or returned
garbage, so there is no usable classification). Priority of reasons: ``clock_jump`` >
``estimator_unhealthy`` > ``classifier_error`` > ``no_classification`` > ``stale_classification``.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Sequence

import numpy as np

from terrainml.lookup.policy import PolicyDecision, choose


def decide(probabilities: np.ndarray | None, class_ids: Sequence[int], age_s: float | None,
           estimator_ok: bool, table, *, states: Sequence[str], v_long: Sequence[float],
           classifier_error: bool = False, clock_jump: bool = False,
           max_age_s: float = 1.0) -> PolicyDecision:
    """Served class, per-wheel desired slip, fallback flag and reason for one tick."""
    if clock_jump:  # the fallback row, whatever the classification says
        dec = choose(None, None, False, table, states=states, v_long=v_long,
                     class_ids=list(class_ids), max_age_s=max_age_s)
        return replace(dec, fallback=True, reason="clock_jump")
    dec = choose(probabilities, age_s, estimator_ok, table, states=states, v_long=v_long,
                 class_ids=list(class_ids), max_age_s=max_age_s)
    if classifier_error and estimator_ok and probabilities is None:
        # choose() already served the fallback row; only the reason is more specific
        dec = replace(dec, fallback=True, reason="classifier_error")
    return dec
