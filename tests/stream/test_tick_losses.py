"""Where the moving ticks of a replay went, on a hand-worked replay of 12 ticks."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from terrainml.evaluation.report import replay_markdown
from terrainml.stream.app.scoring import FALLBACK, NO_MESSAGE, ServedTicks
from terrainml.stream.app.tick_losses import TICK_KINDS, losses_sentence, pooled_tick_losses, tick_losses

# 12 ticks 0.5 s apart at 1 m/s; ground class 0, then class 1 from t = 3.0 s (tick 6)
T = np.arange(12) * 0.5
LABEL = np.array([0] * 6 + [1] * 6)
#                 0  1  2  3  4  5  6  7  8  9         10 11
SERVED = np.array([0, 0, 0, 1, 1, 0, 0, 0, 1, FALLBACK, 1, NO_MESSAGE])
WINDOW = [0, 0, 0, 0, 1, 0, 0, 0, 1, 1, 1, None]    # the latest window's own class at each tick
REASONS = [""] * 9 + ["unknown_terrain", "", ""]


def _ticks() -> ServedTicks:
    msgs = []
    for t, w in zip(T, WINDOW):
        if w is None:
            msgs.append(None)
            continue
        p = [0.0, 0.0]
        p[w] = 1.0
        # each tick serves a new window that ended 0.2 s before it (inside the tick before)
        msgs.append(SimpleNamespace(t_s=float(t), class_probabilities=p, classification_age_s=0.2))
    return ServedTicks(T, LABEL, SERVED, T * 1.0, REASONS, msgs, {}, ["a", "b"])


def test_every_moving_tick_goes_to_one_kind_as_worked_by_hand():
    los = tick_losses(_ticks(), settle_s=1.0)
    # tick 0 has no speed yet and tick 11 no message: 10 moving ticks
    assert los["moving_ticks"] == 10
    assert los["kinds"] == {"right": 5,          # ticks 1, 2, 5, 8, 10
                            "fallback": 1,       # tick 9
                            "transition": 2,     # ticks 6, 7: within 1 s of the change at 3.0 s
                            "fusion_lag": 1,     # tick 3: served 1, its window said 0 (right)
                            "window_wrong": 1,   # tick 4: served 1, its window said 1 too
                            "no_window": 0}
    assert sum(los["kinds"].values()) == los["moving_ticks"]
    assert los["fallback_reasons"] == {"unknown_terrain": 1}
    # windows first served on ticks 1-10, scored against the label of the tick each ended in
    # (the tick before): wrong are tick 4's (1 on class 0) and tick 7's (0 on class 1)
    assert (los["windows_right"], los["windows"]) == (8, 10)


def test_pooled_losses_add_up_and_the_report_shows_them():
    one = tick_losses(_ticks(), settle_s=1.0)
    both = pooled_tick_losses([one, one])
    assert both["moving_ticks"] == 20 and both["windows"] == 20 and both["windows_right"] == 16
    assert both["kinds"] == {k: 2 * one["kinds"][k] for k in TICK_KINDS}
    fold = {"fold": 0, "runs": 2, "moving_ticks": 10, "right_share": 0.5, "losses": one}
    md = "\n".join(replay_markdown({"folds": [fold], "pooled": {"losses": both}, "segment_s": 30.0}))
    assert "Where the moving ticks went" in md
    row = [line for line in md.splitlines() if line.startswith("| all")][-1]  # the losses table's
    assert "80.0" in row and "50.0" in row and "unknown_terrain 10.0" in row


def test_the_sentence_names_every_kind_that_happened_and_the_fallback_reasons():
    line = losses_sentence(tick_losses(_ticks(), settle_s=1.0))
    assert line.startswith("where the 10 moving ticks went: windows right 80.0% of 10; ticks right 50.0%")
    assert "transition 20.0%" in line and "no window" not in line and "unknown_terrain 10.0%" in line


def test_ticks_lost_to_an_unhealthy_estimator_under_way_are_scored_as_its_fallback():
    """Ticks 8-9 fall back with estimator_unhealthy: the odometer adds no distance there (their
    speed is not trusted), but the wheels turn at 1 m/s, so they are moving fallbacks, not left
    out. Tick 10 is unhealthy too with its wheels standing: not moving."""
    odo = T * 1.0
    odo[8:11] = odo[7]                             # the odometer holds over the unhealthy ticks
    odo[11:] = odo[7] + 0.5
    served = SERVED.copy()
    served[8:11] = FALLBACK
    reasons = [""] * 8 + ["estimator_unhealthy"] * 3 + [""]
    rim = np.array([1.0] * 10 + [0.0, 1.0])
    msgs = [SimpleNamespace(t_s=float(t), class_probabilities=[1.0, 0.0], classification_age_s=0.2) for t in T]
    los = tick_losses(ServedTicks(T, LABEL, served, odo, reasons, msgs, {}, ["a", "b"], rim), settle_s=1.0)
    # moving: ticks 1-7 (odometer), 8-9 (wheels); tick 11 gave no message: 9
    assert los["moving_ticks"] == 9 and los["fallback_reasons"] == {"estimator_unhealthy": 2}
    # without the wheels' speed those two would be left out of the score
    los = tick_losses(ServedTicks(T, LABEL, served, odo, reasons, msgs, {}, ["a", "b"]), settle_s=1.0)
    assert los["moving_ticks"] == 7 and los["fallback_reasons"] == {}
