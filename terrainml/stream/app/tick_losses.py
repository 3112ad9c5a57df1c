"""Where the moving ticks of a replay went: what the windows knew against what was served.

A traction controller gets the served class tick by tick, not a window's figure. This module
puts the two side by side for one replay (:class:`~terrainml.stream.app.scoring.ServedTicks`):

* **windows right**: of the windows the predictor classified while the robot moved over labelled
  ground, the share whose own class (the arg-max of the window's probabilities, which every
  message carries as ``class_probabilities``) is the label at the window's end;
* **ticks**: every moving labelled tick (:func:`~terrainml.stream.app.scoring.moving_ticks`) goes
  to exactly one kind of :data:`TICK_KINDS`, in this order:

  ``right``          the labelled class was served;
  ``fallback``       a fallback was served (no class), counted per reason in ``fallback_reasons``;
                     ``unknown_terrain`` there is unknown-ground flagged on known ground;
  ``transition``     a wrong class within ``settle_s`` after a label change (windows still
                     straddle the old ground, and fusion holds the old class on purpose);
  ``fusion_lag``     a wrong class while the latest window's own class was right: fusion over
                     distance had not yet followed the window;
  ``window_wrong``   a wrong class and the latest window's class wrong too: the classifier's error;
  ``no_window``      a class was served but no window had been classified since the timeline
                     began (it cannot happen with the predictor's rules; counted, never hidden).

The shares of the kinds add up to 1. "Windows right" above "ticks right" is what serving loses;
the kinds say where.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from terrainml.stream.app.scoring import FALLBACK, ServedTicks, after_changes, ticks_moving

__all__ = ["TICK_KINDS", "tick_losses", "pooled_tick_losses", "losses_sentence"]

#: the kinds a moving labelled tick is given, in the order it is given one
TICK_KINDS = ("right", "fallback", "transition", "fusion_lag", "window_wrong", "no_window")


def window_classes(messages: Sequence[Any]) -> tuple[np.ndarray, np.ndarray]:
    """Per tick: the class id of the latest window the predictor classified (-1 none), and the
    end time of that window in s (NaN none), read from each message.

    A message carries the latest window's probabilities (``class_probabilities``, by class id)
    and its age (``classification_age_s``, -1 when none); a tick without a message has none.
    """
    n = len(messages)
    cls, t_win = np.full(n, -1, dtype=np.int64), np.full(n, np.nan)
    for i, msg in enumerate(messages):
        if msg is None or msg.classification_age_s < 0:
            continue
        p = np.asarray(msg.class_probabilities, dtype=float)
        if p.size and p.sum() > 0:
            cls[i] = int(np.argmax(p))
            t_win[i] = msg.t_s - msg.classification_age_s
    return cls, t_win


def _window_right(ticks: ServedTicks, moving: np.ndarray, cls: np.ndarray, t_win: np.ndarray) -> tuple[int, int]:
    """(windows right, windows): each window once, at the first tick that serves it, scored
    against the label at its end; only windows first served on a moving labelled tick."""
    new = np.isfinite(t_win) & ~np.isclose(t_win, np.concatenate(([np.nan], t_win[:-1])), equal_nan=True)
    idx = np.flatnonzero(new & moving)
    if not len(idx):
        return 0, 0
    end = np.clip(np.searchsorted(ticks.t_s, t_win[idx], side="right") - 1, 0, len(ticks.t_s) - 1)
    lab = ticks.label[end]
    keep = lab >= 0
    return int((cls[idx][keep] == lab[keep]).sum()), int(keep.sum())


def tick_losses(ticks: ServedTicks, settle_s: float) -> dict[str, Any]:
    """Where the moving labelled ticks of one replay went (module docstring).

    Returns
    -------
    dict: ``settle_s``; ``moving_ticks``; ``windows`` and ``windows_right`` (counts); ``kinds`` (count per
    :data:`TICK_KINDS`); ``fallback_reasons`` (count per reason, moving ticks only).
    """
    moving = ticks_moving(ticks)
    cls, t_win = window_classes(ticks.messages)
    right = ticks.served == ticks.label
    fallback = ticks.served == FALLBACK
    wrong = ~right & ~fallback
    after = after_changes(ticks.t_s, ticks.label, settle_s)
    kinds = {"right": moving & right, "fallback": moving & fallback,
             "transition": moving & wrong & after}
    rest = moving & wrong & ~after
    kinds["fusion_lag"] = rest & (cls == ticks.label)
    kinds["window_wrong"] = rest & (cls >= 0) & (cls != ticks.label)
    kinds["no_window"] = rest & (cls < 0)
    reasons: dict[str, int] = {}
    for i in np.flatnonzero(kinds["fallback"]):
        reasons[ticks.reasons[i]] = reasons.get(ticks.reasons[i], 0) + 1
    w_right, w_n = _window_right(ticks, moving, cls, t_win)
    return {"settle_s": float(settle_s), "moving_ticks": int(moving.sum()), "windows": w_n, "windows_right": w_right,
            "kinds": {k: int(v.sum()) for k, v in kinds.items()},
            "fallback_reasons": dict(sorted(reasons.items()))}


def pooled_tick_losses(parts: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The sum of several replays' :func:`tick_losses` (counts add up)."""
    out: dict[str, Any] = {"settle_s": parts[0]["settle_s"] if parts else float("nan"), "moving_ticks": 0,
                           "windows": 0, "windows_right": 0, "kinds": dict.fromkeys(TICK_KINDS, 0),
                           "fallback_reasons": {}}
    for p in parts:
        for k in ("moving_ticks", "windows", "windows_right"):
            out[k] += p[k]
        for k, v in p["kinds"].items():
            out["kinds"][k] += v
        for r, v in p["fallback_reasons"].items():
            out["fallback_reasons"][r] = out["fallback_reasons"].get(r, 0) + v
    out["fallback_reasons"] = dict(sorted(out["fallback_reasons"].items()))
    return out


def losses_sentence(los: dict[str, Any]) -> str:
    """One line for a person: windows right, then where the moving ticks went (:func:`tick_losses`)."""
    n = los["moving_ticks"]
    windows = (f"windows right {los['windows_right'] / los['windows']:.1%} of {los['windows']}; "
               if los["windows"] else "no window classified; ")
    kinds = ", ".join(f"{k.replace('_', ' ')} {v / n:.1%}" for k, v in los["kinds"].items() if v)
    reasons = ", ".join(f"{r} {v / n:.1%}" for r, v in los["fallback_reasons"].items())
    return (f"where the {n} moving ticks went: {windows}ticks {kinds}"
            + (f" (fallback reasons: {reasons})" if reasons else ""))
