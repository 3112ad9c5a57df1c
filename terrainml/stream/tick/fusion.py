"""Temporal fusion of class probabilities over distance travelled (design §11).

The terrain under a robot changes with the ground it covers, not with time: a robot standing
still stays on the same terrain. :class:`TerrainFilter` is a discrete Bayes filter (an HMM
forward pass) over the model's K classes whose clock is the odometer:

* **predict** (every tick, distance increment Δd >= 0 m): the class persists with probability
  ``p_stay = exp(-Δd / L)`` (L = ``length_m``, the mean distance between transitions) and
  otherwise moves to any other class uniformly::

      b_k <- p_stay b_k + (1 - p_stay) (1 - b_k) / (K - 1)

  With Δd = 0 (standing still) nothing changes: a classification is held across stops.
* **update** (each classification, probabilities p of the window): the classifier's
  probabilities (trained on balanced classes) stand for likelihoods; consecutive windows overlap,
  so each is tempered by ``alpha`` (a likelihood ``(p + eps)^alpha``), then ``b`` is normalised.
* **change detector**: a one-sided CUSUM on the surprise of the held class,
  ``g <- max(0, g - log(p_held + eps) - drift)``; above ``threshold`` the terrain has likely
  changed, so the filter restarts from the latest probabilities (``b <- p`` mixed with a little
  uniform) and the served class can switch within a window or two instead of waiting for the
  prior to decay.
* **confirmation** (``confirm_windows`` = K): after an alarm the filter restarts, but the class
  served before it is held (:meth:`best`) until K consecutive windows name the same class; the
  filter then restarts from the last of them. A window that straddles the transition (the robot
  takes about 1 m to cross one) often names a third class for a window or two; served at once,
  that is a wrong switch. The predictor confirms over :data:`CONFIRM_S` = 0.2 s of windows
  (:func:`confirm_windows_for`): K = 3 at the ``short`` spec's 0.1 s hop, chosen on the tuning
  transition courses (seeds 9201-9202, 9301-9312; docs/stream.md "Transitions"; switches per
  transition 1.25 -> 1.04 on stop-and-go at 94.1 -> 92.6% accuracy), and K = 1 (serve the
  restart at once) at a 0.5 s hop, where each window more delays a real change by 0.5 s
  (measured with K = 3 there: the `steady` mixed course 86% instead of >= 90%, a BorealTC course
  76% instead of >= 80%).
* **age in metres**: distance since the last classification (``age_m``); beyond ``stale_m``
  (default 3 m) without a fresh one the fused class is stale.
* **unknown ground**: a window may come with its novelty flag (the model's
  :class:`~terrainml.models.novelty.NoveltyScorer` over its threshold). ``unknown_windows`` = U
  consecutive flagged windows make the filter :attr:`~TerrainFilter.unknown` (the policy serves
  the safe cap with ``unknown_terrain``); while unknown, the windows' closed-set probabilities
  are not fused (they name a class the ground is not). It ends like a class change is
  confirmed: max(K, U) consecutive windows that are not flagged and name one class; the filter
  then restarts from the last of them and serves it. U is 1 + round((window length +
  :data:`UNKNOWN_CONFIRM_S`) / hop) (:func:`unknown_windows_for`: 5 for 1 s windows at a 0.5 s
  hop), so a terrain change's straddling windows and a window or two over
  the threshold (at most about 5 % of moving known windows are, by the threshold's design) never leave the class;
  leaving takes at least U windows too, because at a 0.5 s hop K is 1 and one closed-set
  window that looks known on new ground would end the stretch.
  **Settling** (``settle_m``, :data:`SETTLE_M`): a change between two *known* terrains is flagged
  longer than its straddle: until every wheel has crossed and the drive has settled on the new
  ground (the currents of a wheel leaving mud take metres to settle), 0.8-3.7 m of flags on the
  tuning courses. A flagged stretch that begins after ``settle_m`` of known ground therefore
  enters unknown only once it has lasted ``settle_m`` of travel too (odometer of :meth:`predict`);
  one that begins without known ground before it (start-up, or right after another stretch) needs
  only its U windows. A blip of fewer than K flagged windows does not end the known ground (a
  robot starting again after a stop has one or two, its drive settling: on the tuning stop-and-go
  courses, with a model trained on its first logs, each such blip let the next terrain change
  enter unknown in U windows; `unknown_terrain` on known ground 3.4% -> 0.9% of moving ticks); K
  flags in a row do, as they would confirm a class change. Ground whose only flags are that
  settling is not entered: on the tuning courses steady dry_sand (held out) is rarely flagged, so
  its entries at settle_m = 0 came from the change into it, not from the sand. A window without a
  flag (a model without a novelty scorer) changes nothing here: the filter serves exactly as
  before.

All numbers are finite by construction (``eps`` floors the likelihoods); K-vectors are small and
each call costs a few microseconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

__all__ = ["TerrainFilter", "FusionConfig", "CONFIRM_S", "SETTLE_M", "STALE_M", "UNKNOWN_CONFIRM_S",
           "confirm_windows_for", "fusion_settings", "unknown_windows_for"]

#: seconds of windows over which a change alarm is confirmed (tuning courses)
CONFIRM_S = 0.2
#: seconds of flagged windows, beyond one window length, that make the ground unknown.
#: A terrain change is flagged too: the windows that straddle it (one window length of them) are
#: unlike either class. Counting one window length more than that straddle keeps a change of known
#: ground from entering unknown alone (the demo course: 540 unknown ticks, 91% right, with 1.0 s
#: and no window length; none, 94.4%, with it), while unknown ground is entered within window
#: length + 1 s of its first flagged window (2 s for the 1 s ``short`` windows, 2 m at 1 m/s).
UNKNOWN_CONFIRM_S = 1.0
#: m of travel that a flagged stretch must last to make the ground unknown when it begins on known
#: ground: a change between known terrains stays flagged while the robot's wheels
#: straddle it and its drive settles (mud on a wheel, the speed loop catching up), measured 0.8-3.7
#: m on the tuning courses (seeds 9301-9304, docs/stream.md "Unknown ground"). Chosen there with
#: the demo's model: served right 88.6% -> 93.4% of moving ticks (94.2% without novelty) while
#: steadily flagged unknown ground (wet_mud, tilled_loam held out) is entered within 2.8 m.
SETTLE_M = 2.5
#: m travelled since the last classification beyond which the fused class is stale
STALE_M = 3.0


def confirm_windows_for(hop_s: float, confirm_s: float = CONFIRM_S) -> int:
    """K for a classification every ``hop_s`` seconds: the alarm window plus ``confirm_s`` of
    windows after it, 1 + round(confirm_s / hop_s) (3 at a 0.1 s hop, 1 at 0.5 s)."""
    if not float(hop_s) > 0:
        raise ValueError(f"confirm_windows_for: hop_s must be > 0, got {hop_s!r}")
    return 1 + int(round(float(confirm_s) / float(hop_s)))


def unknown_windows_for(hop_s: float, window_s: float = 0.0, confirm_s: float = UNKNOWN_CONFIRM_S) -> int:
    """U for ``window_s`` windows classified every ``hop_s`` seconds: 1 + round((window_s +
    confirm_s) / hop_s) flagged windows make the ground unknown (5 for 1 s windows at a 0.5 s hop)."""
    return confirm_windows_for(hop_s, float(window_s) + confirm_s)


@dataclass(frozen=True)
class FusionConfig:
    """The serving config's :class:`TerrainFilter` settings (``ServingConfig.fusion``).

    A field left None takes the filter's own default (``length_m``, ``alpha``, ``eps``, ``drift``,
    ``threshold``) or the value the model's hop and window length give (``confirm_windows``:
    :func:`confirm_windows_for` the hop, 3 at 0.1 s, 1 at 0.5 s; ``unknown_windows``:
    :func:`unknown_windows_for` the hop and window length, 5 for 1 s windows at 0.5 s).
    ``settle_m`` (m) is :data:`SETTLE_M` unless set. Units and meanings: :class:`TerrainFilter`.
    """

    length_m: float | None = None
    alpha: float | None = None
    eps: float | None = None
    drift: float | None = None
    threshold: float | None = None
    confirm_windows: int | None = None
    unknown_windows: int | None = None
    settle_m: float = SETTLE_M


def fusion_settings(hop_s: float, config: FusionConfig | None = None, window_s: float = 0.0) -> dict:
    """The predictor's :class:`TerrainFilter` keyword settings for its hop (s) and window
    length (s): those ``config`` sets, the hop's ``confirm_windows`` and ``unknown_windows``."""
    cfg = config or FusionConfig()
    settings = {f.name: getattr(cfg, f.name) for f in fields(cfg) if getattr(cfg, f.name) is not None}
    settings.setdefault("confirm_windows", confirm_windows_for(hop_s))
    settings.setdefault("unknown_windows", unknown_windows_for(hop_s, window_s))
    return settings


class TerrainFilter:
    """Discrete Bayes filter over terrain classes with a transition prior per metre.

    Parameters
    ----------
    n_classes : int >= 1, K.
    length_m : float > 0, L in p_stay = exp(-d / L), m (default 20: a class persists over metres).
    alpha : float in (0, 1], likelihood temper for overlapping windows (default 0.35).
    eps : float > 0, likelihood floor (default 0.02).
    drift : float >= 0, CUSUM allowance per classification, nats (default 1.5).
    threshold : float > 0, CUSUM alarm level, nats (default 4.0).
    stale_m : float > 0, distance after the last classification beyond which the fused class is
        stale, m (default 3.0).
    confirm_windows : int >= 1, K: consecutive windows that must name one class after an alarm
        before the filter serves it; the class from before the alarm is served meanwhile
        (default 1: the restart is served at once; the predictor uses
        :func:`confirm_windows_for` its hop).
    unknown_windows : int >= 1, U: consecutive windows flagged unknown (the ``unknown`` argument
        of :meth:`update`) that make the ground unknown; max(K, U) known windows naming one class
        end it (default 2; the predictor uses :func:`unknown_windows_for` its hop).
    settle_m : float >= 0, m: a flagged stretch that begins after at least ``settle_m`` of known
        ground (a change of terrain, as far as the filter can tell) makes the ground unknown only
        once it has also lasted ``settle_m`` of travel (default 0: U windows suffice; the
        predictor uses :data:`SETTLE_M`).

    Attributes
    ----------
    posterior : ndarray (K,) or None before the first classification.
    age_m : float, m travelled since the last classification (inf before the first).
    n_changes : int, change-detector alarms so far.
    pending : bool, an alarm awaits confirmation (:meth:`best` reports the held class).
    unknown : bool, the latest windows are unknown ground (module docstring).
    novelty : float, the latest window's novelty score over its threshold (> 1: flagged); -1.0
        when no window came with a score.
    """

    def __init__(self, n_classes: int, *, length_m: float = 20.0, alpha: float = 0.35,
                 eps: float = 0.02, drift: float = 1.5, threshold: float = 4.0,
                 stale_m: float = STALE_M, confirm_windows: int = 1, unknown_windows: int = 2,
                 settle_m: float = 0.0):
        if int(n_classes) < 1:
            raise ValueError("TerrainFilter: n_classes must be >= 1")
        for name, v in (("confirm_windows", confirm_windows), ("unknown_windows", unknown_windows)):
            if int(v) != v or int(v) < 1:
                raise ValueError(f"TerrainFilter: {name} must be an integer >= 1, got {v!r}")
        for name, v in (("length_m", length_m), ("eps", eps), ("threshold", threshold),
                        ("stale_m", stale_m)):
            if not float(v) > 0:
                raise ValueError(f"TerrainFilter: {name} must be > 0, got {v!r}")
        if not 0 < float(alpha) <= 1:
            raise ValueError(f"TerrainFilter: alpha must be in (0, 1], got {alpha!r}")
        for name, v in (("drift", drift), ("settle_m", settle_m)):
            if not (float(v) >= 0 and math.isfinite(float(v))):
                raise ValueError(f"TerrainFilter: {name} must be finite and >= 0, got {v!r}")
        self.n_classes = int(n_classes)
        self.length_m = float(length_m)
        self.alpha = float(alpha)
        self.eps = float(eps)
        self.drift = float(drift)
        self.threshold = float(threshold)
        self.stale_m = float(stale_m)
        self.confirm_windows = int(confirm_windows)
        self.unknown_windows = int(unknown_windows)
        self.settle_m = float(settle_m)
        self.reset()

    def reset(self) -> None:
        """Forget everything (a new timeline)."""
        self.posterior: np.ndarray | None = None
        self.age_m = math.inf
        self.cusum = 0.0
        self.n_changes = 0
        self.n_updates = 0
        self.pending = False
        self._held = (-1, 0.0)     # (class, posterior) served while an alarm awaits confirmation
        self._run = (-1, 0)        # (class, consecutive windows naming it) since the alarm
        self.unknown = False
        self.novelty = -1.0
        self.n_unknown_stretches = 0
        self._flagged = 0          # consecutive windows flagged unknown
        self._known = (-1, 0)      # (class, consecutive known windows naming it) while unknown
        self._odometer_m = 0.0     # m travelled since reset
        self._known_since_m = math.inf  # odometer at the first window of the latest unflagged stretch
        self._flags_since_m = 0.0  # odometer at the first window of the latest flagged stretch
        self._after_known = False  # that flagged stretch began after settle_m of known ground

    # ------------------------------------------------------------------ filter
    def predict(self, distance_m: float) -> None:
        """Advance by ``distance_m`` (m, >= 0; non-finite or negative counts as 0)."""
        d = float(distance_m)
        if not (d > 0 and math.isfinite(d)):
            return
        self.age_m += d
        self._odometer_m += d
        b = self.posterior
        if b is None or self.n_classes == 1:
            return
        p_stay = math.exp(-d / self.length_m)
        b = p_stay * b + (1.0 - p_stay) * (1.0 - b) / (self.n_classes - 1)
        self.posterior = b / b.sum()

    def update(self, probabilities: np.ndarray, unknown: bool | None = None,
               novelty: float = -1.0) -> bool:
        """Fuse one classification (K probabilities); return True when a change was detected.

        ``unknown``: the window's novelty flag (None: no novelty score; on
        unknown ground, e.g. a sensor member without a scorer serving, it counts as not flagged);
        ``novelty``: its score over the threshold (the message's ``novelty``).
        """
        p = np.asarray(probabilities, dtype=float).ravel()
        if p.shape[0] != self.n_classes:
            raise ValueError(f"TerrainFilter: {p.shape[0]} probabilities for {self.n_classes} classes")
        self.age_m = 0.0
        self.n_updates += 1
        if (unknown is not None or self.unknown) and self._unknown_ground(p, bool(unknown), float(novelty)):
            return False
        if self.posterior is None:
            self.posterior = self._restart(p)
            return False
        held = int(np.argmax(self.posterior))
        self.cusum = max(0.0, self.cusum - math.log(p[held] + self.eps) - self.drift)
        if self.cusum > self.threshold:  # the held class no longer explains the windows
            self.cusum = 0.0
            self.n_changes += 1
            if not self.pending:  # serve the class from before the alarm until one is confirmed
                self._held = self.best()
            self.pending = self.confirm_windows > 1
            self._run = (int(np.argmax(p)), 1)
            self.posterior = self._restart(p)
            return True
        b = self.posterior * (p + self.eps) ** self.alpha
        self.posterior = b / b.sum()
        if self.pending:
            k = int(np.argmax(p))
            self._run = (k, self._run[1] + 1 if k == self._run[0] else 1)
            if self._run[1] >= self.confirm_windows:  # K windows agree: serve from the last one
                self.pending = False
                self.posterior = self._restart(p)
        return False

    def _unknown_ground(self, p: np.ndarray, flagged: bool, novelty: float) -> bool:
        """Track the novelty flags; True when the window is not to be fused (unknown ground)."""
        self.novelty = novelty if math.isfinite(novelty) else -1.0
        self._track_stretches(flagged)
        if not self.unknown:
            if self._flagged >= self.unknown_windows and self._settled():
                self.unknown, self._known = True, (-1, 0)
                self.n_unknown_stretches += 1
                return True
            return False
        if flagged:
            self._known = (-1, 0)
            return True
        k = int(np.argmax(p))
        self._known = (k, self._known[1] + 1 if k == self._known[0] else 1)
        if self._known[1] < max(self.confirm_windows, self.unknown_windows):
            return True
        # known again, confirmed like a class change: serve the class from the last window
        self.unknown, self.pending, self.cusum = False, False, 0.0
        self._known_since_m = self._odometer_m
        self.posterior = self._restart(p)
        return True

    def _track_stretches(self, flagged: bool) -> None:
        """Count consecutive flagged windows and note where each flagged and known stretch began."""
        if flagged:
            if self._flagged == 0:  # a flagged stretch begins: after how much known ground?
                self._flags_since_m = self._odometer_m
                self._after_known = (not self.unknown
                                     and self._odometer_m - self._known_since_m >= self.settle_m)
            self._flagged += 1
            return
        # a blip of fewer than K flags (a restart after a stop: the drive settling) leaves the known
        # ground known; K flags in a row end it, as they would confirm a class change
        if self._flagged >= self.confirm_windows or not math.isfinite(self._known_since_m):
            self._known_since_m = self._odometer_m
        self._flagged = 0

    def _settled(self) -> bool:
        """True when the flagged stretch is not a change of known ground still settling: it began
        without settle_m of known ground before it, or it has lasted settle_m itself."""
        return not self._after_known or self._odometer_m - self._flags_since_m >= self.settle_m

    def _restart(self, p: np.ndarray) -> np.ndarray:
        """A posterior from one classification: its probabilities, floored like a likelihood."""
        b = p + self.eps
        return b / b.sum()

    # ------------------------------------------------------------------ read-out
    @property
    def stale(self) -> bool:
        """True when more than ``stale_m`` travelled since the last classification."""
        return self.age_m > self.stale_m

    def best(self) -> tuple[int, float]:
        """(index of the most probable class, its posterior probability); (-1, 0.0) if none.

        While an alarm awaits confirmation: the class and posterior from before the alarm.
        """
        if self.pending:
            return self._held
        if self.posterior is None:
            return -1, 0.0
        k = int(np.argmax(self.posterior))
        return k, float(self.posterior[k])
