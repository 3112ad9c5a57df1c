"""The stream's clock policy: which time stamps are ticks, and how the stream re-anchors (design §11).

The predictor follows one *timeline*: ``t_last``, the ``t_s`` of the last tick it accepted. The
first sample anchors it. Each later stamp ``t`` is, with ``G = max_gap_s`` (default 1.0 s):

==============================  ===========  ==========================================================
stamp                           verdict      what the predictor does
==============================  ===========  ==========================================================
``t_last < t <= t_last + G``    ``accept``   the next tick: estimated, classified, served
``t == t_last``                 ``duplicate`` dropped (no message), counted
``t_last - G <= t < t_last``    ``late``     a re-ordered sample: dropped (no message), counted
anything else                   ``jump``     a clock jump (forward or backward by more than G): served
                                             with the fallback row, ``fallback_reason="clock_jump"``,
                                             ``estimator_ok=false``; the estimator never sees it
K-th consistent jump            ``reanchor`` the stream re-anchors: estimator, health monitor, window
                                             buffer and classification restart, and this sample is
                                             the first tick of the new timeline
==============================  ===========  ==========================================================

Consecutive off-timeline samples that agree with each other (each ``0 < dt <= G`` after the
previous one) form a *candidate* timeline; ``reanchor_after`` (K, default 5) of them re-anchor the
stream on it. A sample back on the old timeline ends the candidate, so a lone wild stamp (t = 1e12
in the middle of a run) costs one ``clock_jump`` tick and nothing else. An absurd first stamp
(t = -1e12) is a timeline of one sample: the K samples after it are clock jumps, and the K-th
re-anchors. A backward step of at most G is never a jump: those samples are late and dropped until
the stamps pass ``t_last`` again, so the stream is silent for at most G of stream time. The
stream therefore never wedges: every stamp is a tick, a counted drop of bounded length, or a
served ``clock_jump`` tick on the way to re-anchoring.

Each jump episode and each re-anchoring is logged as a warning when it happens (the first 10,
then every 100th), and counted in :class:`~terrainml.stream.tick.health.InputCounters`
(``clock_jump``, ``reanchors``, ``duplicate``, ``out_of_order``).
"""

from __future__ import annotations

import logging
import math

from terrainml.stream.tick.health import InputCounters

log = logging.getLogger("terrainml.stream")

ACCEPT, DUPLICATE, LATE, JUMP, REANCHOR = "accept", "duplicate", "late", "jump", "reanchor"

#: default largest step (s) between consecutive ticks of one timeline
MAX_GAP_S = 1.0
#: default number of consistent off-timeline samples that re-anchor the stream (K)
REANCHOR_AFTER = 5


def _loud(n: int) -> bool:
    """Log the first 10 events of a kind, then every 100th (a flood must not flood stderr)."""
    return n <= 10 or n % 100 == 0


class ClockGate:
    """Classify each sample's ``t_s`` against the timeline (policy in the module docstring).

    Parameters
    ----------
    counters : InputCounters, updated in place.
    max_gap_s : float, s, > 0. Largest step between consecutive ticks of one timeline.
    reanchor_after : int, >= 1. Consistent off-timeline samples that re-anchor the stream (K).
    """

    def __init__(self, counters: InputCounters | None = None, *, max_gap_s: float = MAX_GAP_S,
                 reanchor_after: int = REANCHOR_AFTER):
        if not (isinstance(max_gap_s, (int, float)) and math.isfinite(max_gap_s) and max_gap_s > 0):
            raise ValueError(f"max_gap_s must be a finite number > 0, got {max_gap_s!r}")
        if isinstance(reanchor_after, bool) or not isinstance(reanchor_after, int) or reanchor_after < 1:
            raise ValueError(f"reanchor_after must be an int >= 1, got {reanchor_after!r}")
        self.counters = counters if counters is not None else InputCounters()
        self.max_gap_s = float(max_gap_s)
        self.reanchor_after = reanchor_after
        self.last_t_s: float | None = None
        self._cand_t: float | None = None  # last stamp of the candidate timeline
        self._cand_n = 0  # its length
        self._episodes = 0

    def check(self, t_s: float) -> str:
        """Verdict for a finite stamp ``t_s`` (s): ACCEPT, DUPLICATE, LATE, JUMP or REANCHOR."""
        c = self.counters
        last = self.last_t_s
        if last is None or last < t_s <= last + self.max_gap_s:
            if self._cand_t is not None:
                log.info("clock back on its timeline at t=%.6g s after %d off-timeline sample(s)",
                         t_s, self._cand_n)
                self._cand_t, self._cand_n = None, 0
            self.last_t_s = t_s
            c.accepted += 1
            return ACCEPT
        if t_s == last:
            c.duplicate += 1
            return DUPLICATE
        if last - self.max_gap_s <= t_s < last:
            c.out_of_order += 1
            if _loud(c.out_of_order):
                log.warning("late sample dropped: t=%.6g s after t=%.6g s (%d so far)", t_s, last,
                            c.out_of_order)
            return LATE
        return self._off_timeline(t_s, last)

    def _off_timeline(self, t_s: float, last: float) -> str:
        c = self.counters
        cand = self._cand_t
        if cand is not None and t_s == cand:
            c.duplicate += 1
            return DUPLICATE
        if cand is not None and cand < t_s <= cand + self.max_gap_s:
            self._cand_n += 1
        else:
            if cand is None:
                self._episodes += 1
                if _loud(self._episodes):
                    log.warning("clock jump: t=%.6g s after t=%.6g s (episode %d); serving "
                                "clock_jump fallback until %d consistent samples re-anchor the stream",
                                t_s, last, self._episodes, self.reanchor_after)
            self._cand_n = 1
        self._cand_t = t_s
        if self._cand_n < self.reanchor_after:
            c.clock_jump += 1
            return JUMP
        self.last_t_s = t_s
        self._cand_t, self._cand_n = None, 0
        c.reanchors += 1
        c.accepted += 1
        if _loud(c.reanchors):
            log.warning("clock re-anchored at t=%.6g s (was t=%.6g s; %d so far): estimator, health "
                        "and classification restarted", t_s, last, c.reanchors)
        return REANCHOR
