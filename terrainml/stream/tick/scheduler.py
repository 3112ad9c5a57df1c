"""When the online predictor classifies, on which thread, and what a result does (design §11).

:class:`ClassificationScheduler` runs at most one classification per online hop of the window
spec, on the latest full window of the ring buffer (:mod:`terrainml.stream.tick.ring`), and only
after the robot has moved (standing still the window holds nothing new about the ground).
Inline (``lag_ticks`` 0) the tick classifies; otherwise the tick only snapshots the ring and a
background thread classifies, its result applied exactly ``lag_ticks`` ticks later (the tick
waits for it if needed: deterministic). A result feeds the fusion filter
(:class:`~terrainml.stream.tick.fusion.TerrainFilter`); a window the steady rules reject (``None``)
keeps the previous classification and counts the rules it failed (:attr:`ClassificationScheduler.rejections`;
:meth:`ClassificationScheduler.silence` names the rule once the robot has moved a set distance
without a classification); any exception is caught, counted and served as
``classifier_error`` (:mod:`terrainml.stream.tick.policy`) until a later classification succeeds.
A classifier with a novelty scorer leaves the window's ``last_novelty`` (score over threshold,
flagged), which goes to the filter with the probabilities (unknown ground).

The classification thread runs under the interpreter's own GIL switch interval: nothing
process-wide is changed (lowering it measured no better, often worse, for the paced per-tick
p99; figures in ``docs/stream.md``, Performance).
"""

from __future__ import annotations

import logging
import time
from collections import Counter, deque
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Protocol, Sequence

import numpy as np
import pandas as pd

from terrainml.stream.tick.fusion import TerrainFilter
from terrainml.stream.tick.ring import RingBuffer, is_label

__all__ = ["MIN_MOVE_M", "ClassificationScheduler", "SilenceWatch", "WindowClassifierLike"]

log = logging.getLogger("terrainml.stream")

#: distance the robot must cover between two classification attempts (m): none standing still
MIN_MOVE_M = 0.01


class WindowClassifierLike(Protocol):
    """What the predictor needs from a classifier: probabilities for a window, or None."""

    class_ids: Sequence[int]

    def classify(self, window: pd.DataFrame) -> np.ndarray | None: ...


class ClassificationScheduler:
    """Classification of the latest window every hop, inline or in a background thread.

    Parameters
    ----------
    classifier : ``classify(window_df)`` (and optionally ``classify_columns(columns)``, the
        serving path), or None: never classifies.
    ring : the predictor's ring buffer (one window of EST rows).
    fused : the fusion filter the probabilities update (reset on a classifier error).
    hop_s : s, the window spec's online hop (at most one attempt per hop).
    lag_ticks : 0 inline; L > 0 background thread, result applied L ticks later.
    n_classes : K, the length of the probabilities a classification must return.
    """

    def __init__(self, classifier: WindowClassifierLike | None, ring: RingBuffer,
                 fused: TerrainFilter, hop_s: float, lag_ticks: int, n_classes: int):
        self.classifier = classifier
        self.ring = ring
        self.fused = fused
        self.hop_s = float(hop_s)
        self.n_samples = ring.capacity  # rows of the classifier's window (the newest of the ring)
        self.lag_ticks = int(lag_ticks)
        self.n_classes = int(n_classes)
        self.probs: np.ndarray | None = None     # (K,) latest classification, normalised
        self.class_t: float | None = None        # s, end of its window
        self.error = False                       # the last attempt raised
        self.last_attempt_t: float | None = None
        self.n_classifications = 0
        self.n_errors = 0
        self.n_unsteady = 0
        self.classify_ms: deque[float] = deque(maxlen=10000)  # bounded: flat memory
        self.wait_ms: deque[float] = deque(maxlen=10000)
        self._executor: Any = None
        self._pending: Any = None
        self._pending_age = 0
        self._odo_at_attempt: float | None = None
        # rejected windows: per rule (a window may fail several) and per invalid channel, over
        # the stream and since the last classification, which started at odometer ``odo_at_class``
        self.rejections: Counter[str] = Counter()
        self.rejected_channels: Counter[str] = Counter()
        self.rules_since: Counter[str] = Counter()
        self.channels_since: Counter[str] = Counter()
        self.odo_at_class: float | None = None
        self._odo_now = 0.0

    def tick(self, t: float, odometer_m: float) -> None:
        """Apply a due background result, then start an attempt if one is due at ``t`` (s)."""
        if self.classifier is None:
            return
        self._odo_now = odometer_m
        if self.odo_at_class is None:  # a timeline starts: its distance without a class from here
            self.odo_at_class = odometer_m
        # 1. a pending background classification is applied exactly `lag_ticks` later
        if self._pending is not None:
            fut, t_win, due, clf = self._pending
            self._pending_age += 1
            if self._pending_age >= due:
                self._pending = None
                c0 = time.perf_counter()
                try:
                    self._apply(fut.result(), t_win, clf)
                except Exception as exc:  # noqa: BLE001
                    self._fail(t_win, exc)
                self.wait_ms.append((time.perf_counter() - c0) * 1e3)
        # 2. at most one new classification per hop, on the latest full window
        if self.ring.count < self.n_samples or self._pending is not None:
            return
        if self.last_attempt_t is not None and t - self.last_attempt_t < self.hop_s - 1e-9:
            return
        # standing still the window holds nothing new about the ground: skip (and save the cost)
        if self._odo_at_attempt is not None and odometer_m - self._odo_at_attempt < MIN_MOVE_M:
            return
        self.last_attempt_t = t
        self._odo_at_attempt = odometer_m
        snap = self.ring.snapshot(self.n_samples)
        if self.lag_ticks > 0:
            if self._executor is None:
                self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="classify")
            clf = self.classifier  # bound now: a member switch must not change this window's model
            self._pending = (self._executor.submit(self._timed_classify, snap, clf), t, self.lag_ticks, clf)
            self._pending_age = 0
            return
        try:
            self._apply(self._timed_classify(snap), t, self.classifier)
        except Exception as exc:  # noqa: BLE001 - classification must never crash serving
            self._fail(t, exc)

    def use(self, classifier: WindowClassifierLike, hop_s: float, n_samples: int) -> None:
        """Classify from now on with ``classifier`` (a sensor member): its hop (s) and window rows.

        The fused probabilities, a pending result and the rejection counts carry over: the
        members share the class ids and the ground under the robot has not changed.
        """
        self.classifier = classifier
        self.hop_s = float(hop_s)
        self.n_samples = min(int(n_samples), self.ring.capacity)

    def reset(self) -> None:
        """A new timeline: no classification, none pending (an old window's result is dropped)."""
        self._pending = None
        self.probs = None
        self.class_t = None
        self.last_attempt_t = None
        self.error = False
        self._odo_at_attempt = None
        self.odo_at_class = None
        self.rules_since.clear()
        self.channels_since.clear()

    def silence(self, odometer_m: float, after_m: float) -> str | None:
        """Why no window was classified over more than ``after_m`` m travelled, or None.

        None while the robot has covered at most ``after_m`` (m, healthy ticks: the predictor's
        odometer) since the last classification (or the start of the timeline), or when no window
        was rejected in that stretch. Otherwise the rule that rejected the most windows since, with
        the channels it found invalid for ``channel_valid``, e.g. ``"channel_valid: imu_wx"``.
        """
        if self.odo_at_class is None or not odometer_m - self.odo_at_class > after_m:
            return None
        if not self.rules_since:
            return None
        rule = max(self.rules_since, key=lambda r: (self.rules_since[r], r))
        if rule == "channel_valid" and self.channels_since:
            top = max(self.channels_since.values())
            names = sorted(c for c, n in self.channels_since.items() if n == top)
            return f"{rule}: {', '.join(names)}"
        return rule

    def classify_snapshot(self, snap: tuple[np.ndarray, np.ndarray] | None,
                          classifier: Any = None) -> np.ndarray | None:
        """Probabilities for the latest window of a ring :meth:`~RingBuffer.snapshot` (or None).

        The serving path: the classifier (default the current one) reads the snapshot's columns
        in place (:meth:`RingBuffer.column_view`, labels left out), no DataFrame is built.
        """
        clf = self.classifier if classifier is None else classifier
        fast = getattr(clf, "classify_columns", None)
        if fast is not None:  # column arrays straight from the ring: no DataFrame
            return fast(self.ring.column_view(snap, is_label))
        return clf.classify(self.ring.to_frame(snap))  # type: ignore[union-attr]

    def close(self) -> None:
        """Stop the background classification thread (if any)."""
        if self._executor is not None:
            self._executor.shutdown(wait=True)
            self._executor = None

    def _timed_classify(self, snap: tuple[np.ndarray, np.ndarray] | None,
                        classifier: Any = None) -> np.ndarray | None:
        c0 = time.perf_counter()
        try:
            return self.classify_snapshot(snap, classifier)
        finally:
            self.classify_ms.append((time.perf_counter() - c0) * 1e3)

    def _apply(self, probs: Any, t_win: float, classifier: Any = None) -> None:
        if probs is None:  # latest window not steady: keep the previous classification
            self.n_unsteady += 1
            rej = getattr(classifier, "last_rejection", None)
            if rej is not None:
                self.rejections.update(rej.rules)
                self.rules_since.update(rej.rules)
                self.rejected_channels.update(rej.channels)
                self.channels_since.update(rej.channels)
            return
        p = np.asarray(probs, dtype=float).ravel()
        if p.shape[0] != self.n_classes or not np.all(np.isfinite(p)) or p.sum() <= 0:
            raise ValueError(f"classifier returned invalid probabilities {p!r}")
        p = np.clip(p, 0.0, None)
        self.probs = p / p.sum()
        self.class_t = t_win
        self.error = False
        self.n_classifications += 1
        self.odo_at_class = self._odo_now
        self.rules_since.clear()
        self.channels_since.clear()
        nov = getattr(classifier, "last_novelty", None)
        self.fused.update(self.probs, *(() if nov is None else (nov[1], nov[0])))

    def _fail(self, t: float, exc: BaseException) -> None:
        self.n_errors += 1
        if self.n_errors <= 3:
            log.warning("classification failed at t=%.3f s (serving fallback): %s", t, exc)
        self.probs = None
        self.class_t = None
        self.error = True
        self.fused.reset()


class SilenceWatch:
    """The live warning of ``predict`` that no window is classified.

    :meth:`check` returns the rule rejecting every window once the robot has moved more than
    ``warn_after_m`` (m, healthy ticks) without a classification
    (:meth:`ClassificationScheduler.silence`) and warns once per such stretch, again only for
    another rule and further on.
    """

    def __init__(self, scheduler: ClassificationScheduler, warn_after_m: float):
        self.scheduler, self.warn_after_m = scheduler, float(warn_after_m)
        self._warned: tuple[str, float] | None = None  # (rule, odometer m) of the last warning

    def check(self, t: float, odometer_m: float) -> str | None:
        """The rejecting rule (the served message's ``fallback_detail``) at ``t`` (s), or None."""
        sch, d = self.scheduler, odometer_m
        why = sch.silence(d, self.warn_after_m)
        if why is None:
            self._warned = None
        elif self._warned is None or (why != self._warned[0] and d - self._warned[1] > self.warn_after_m):
            self._warned = (why, d)
            counts = ", ".join(f"{r} {n}" for r, n in sch.rules_since.most_common())
            log.warning("no classification over %.1f m travelled (t=%.1f s, healthy): every window "
                        "is rejected, most by the window rule %r; rejections since the last "
                        "classification: %s", d - (sch.odo_at_class or 0.0), t, why, counts)
        return why
