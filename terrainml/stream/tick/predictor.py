"""The online predictor: one :class:`~terrainml.stream.tick.message.DesiredSlip` per base-rate tick.

:class:`Predictor` is the tick loop of serving (design §11)::

    sample ─ check_sample ─ ClockGate ─ HealthMonitor ─ OnlineEstimator.step ─ RingBuffer ─┬─ ServingPolicy ─ message
                                                                      every hop (0.5 s):    └─ classify latest window

Each stage is its own module; the predictor only hands a tick's facts from one to the next:

* :func:`terrainml.stream.tick.sample.check_sample` rejects anything that is not a sample with
  :class:`~terrainml.stream.tick.sample.InvalidSample` (the one exception :meth:`Predictor.step`
  raises); the clock policy (:mod:`terrainml.stream.tick.clock`) decides which stamps are ticks.
* Estimation is :class:`terrainml.estimation.online.OnlineEstimator` (the same step code the
  offline ``estimate_run`` loops over); its rows (:class:`~terrainml.estimation.row.EstimatorRow`,
  immutable: the tick makes a new one to flag or complete it) go to the column ring buffer
  (:mod:`terrainml.stream.tick.ring`), one window of the model's window spec long.
* Classification (:mod:`terrainml.stream.tick.scheduler`) runs at most once per online hop of the
  window spec, on the latest window, with the offline window and feature code
  (:mod:`terrainml.stream.tick.classify`), inline or in a background thread; its probabilities are
  fused over distance (:mod:`terrainml.stream.tick.fusion`, aged by :mod:`terrainml.stream.tick.odometer`).
* What a tick serves, and every fallback rule with its priority, is
  :class:`terrainml.stream.tick.policy.ServingPolicy`.
* Nothing non-finite reaches the output: non-finite inputs invalidate their sensor group
  (:mod:`terrainml.stream.tick.health`), non-finite estimator outputs make ``estimator_ok`` false and
  are replaced (slip 0, state ``idle``), and the message layer checks again.
* Samples with a duplicate or late ``t_s`` are dropped and counted: :meth:`Predictor.step`
  returns ``None`` for them (the only departure from "one output per input"). A ``t_s`` off the
  timeline (a clock jump) is served as a ``clock_jump`` fallback tick; K consistent ones re-anchor
  the stream, restarting the estimator, health, window buffer and classification.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Mapping
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import Any, Callable, Protocol, Sequence

from terrainml.classes import TERRAIN_CLASSES
from terrainml.estimation.online import OnlineEstimator, flag_groups
from terrainml.estimation.row import EstimatorRow
from terrainml.features.windows import WindowSpec
from terrainml.lookup.wheel_targets import TargetTable
from terrainml.robot import RobotSpec
from terrainml.stream.tick.classify import ServingMember, load_serving_model, one_window_spec
from terrainml.stream.tick.clock import ACCEPT, JUMP, REANCHOR, ClockGate
from terrainml.stream.tick.config import ServingConfig
from terrainml.stream.tick.estimate import WheelRow, warm_up
from terrainml.stream.tick.fusion import TerrainFilter, fusion_settings
from terrainml.stream.tick.health import HealthMonitor, InputCounters
from terrainml.stream.tick.member_vote import Candidate, MemberSwitch, candidate, check_members
from terrainml.stream.tick.message import DesiredSlip
from terrainml.stream.tick.odometer import Odometer
from terrainml.stream.tick.policy import PolicyDecision, ServingPolicy
from terrainml.stream.tick.ring import RingBuffer
from terrainml.stream.tick.sample import InvalidSample, Sample
from terrainml.stream.tick.scheduler import ClassificationScheduler, SilenceWatch, WindowClassifierLike

__all__ = ["InvalidSample", "Predictor"]

log = logging.getLogger("terrainml.stream")

class Estimator(Protocol):
    def step(self, sample: dict) -> Mapping[str, Any]: ...


class Predictor:
    """Online desired-slip predictor (design §10-11).

    Parameters
    ----------
    robot : RobotSpec
    table : desired-slip table with ``target(class_id, state) -> float``
        (:class:`terrainml.lookup.table.DesiredSlipTable`).
    classifier : object with ``class_ids`` and ``classify(window_df) -> probs | None``
        (:class:`terrainml.stream.tick.classify.WindowClassifier`), or None (always fallback). Its
        ``class_names`` (names by class id), when it has them, name the served classes; else the
        eight of design §6.1.
    estimator : object with ``step(sample) -> EST row`` (an
        :class:`~terrainml.estimation.row.EstimatorRow`, or a mapping of EST column names, which is
        typed once); default ``OnlineEstimator(robot, preset)``. On a re-anchor a built one is
        built afresh, an injected one is ``reset()`` if it has that method, else kept.
    window_spec : the model's :class:`~terrainml.features.windows.WindowSpec`, the one spec of
        serving: its window length sizes the ring buffer, its online hop the classification
        rate. None: the classifier's ``window_spec``, else ``WindowSpec()`` (2.0 s, hop 0.5 s,
        100 Hz). A classifier that cuts another spec is refused (ValueError).
    sensors : sensor groups the model needs (health is checked on these; None: all the robot's).
    config : :class:`~terrainml.stream.tick.config.ServingConfig` (fallback rules, fusion, clock
        policy, classification thread, EKF preset); default ``ServingConfig()``.
    members : the model's sensor members (:class:`~terrainml.stream.tick.classify.ServingMember`, best
        first): when a group the model needs is silent, the best member whose groups are all
        fresh classifies (:mod:`terrainml.stream.tick.member_vote`); the message's ``sensors`` says which.
    """

    def __init__(self, robot: RobotSpec, table: TargetTable,
                 classifier: WindowClassifierLike | None = None,
                 estimator: Estimator | None = None, *, window_spec: WindowSpec | None = None,
                 sensors: Sequence[str] | None = None, config: ServingConfig | None = None,
                 members: Sequence[ServingMember] = ()):
        cfg = config or ServingConfig()
        preset = cfg.preset or "robust"
        self.robot, self.table, self.classifier, self.config = robot, table, classifier, cfg
        self.window_spec = one_window_spec(window_spec, classifier)
        warm = estimator is None
        # a re-anchored stream needs a fresh estimator: build one the same way
        self._estimator_factory: Callable[[], Estimator] | None = None
        if estimator is None:
            self._estimator_factory = partial(OnlineEstimator, robot, preset)
            estimator = self._estimator_factory()
        self.estimator = estimator
        # names by class id: the classifier's (a loaded model's own), else the reference's eight
        self.class_names = list(getattr(classifier, "class_names", None) or TERRAIN_CLASSES)
        self.counters = InputCounters()
        self.clock = ClockGate(self.counters, max_gap_s=cfg.max_clock_gap_s,
                               reanchor_after=cfg.reanchor_after)
        # health only on the model's sensor groups (design §9): a model without IMU, or without the
        # camera of a robot that has one, does not read the EKF's flag, whose freshness rule needs
        # both (a silent group still makes a tick unhealthy)
        self.health = HealthMonitor(robot, silent_s=cfg.silent_s, sensors=sensors)
        self.health.counters = self.counters
        self.sensors = None if sensors is None else list(sensors)
        mon = self.health.monitored
        self.switch = MemberSwitch([candidate("model", classifier, self.window_spec, sensors, mon),
                                    *(candidate(m.name, m.classifier, m.window_spec, m.sensors, mon)
                                      for m in members)])
        self._flag_groups = flag_groups(robot)  # what the EKF's own flag needs fresh
        self._estimator_flag = self._flag_groups <= self.switch.active.groups
        #: sensor groups of the model (or member) serving the ticks (the message's ``sensors``)
        self.served_sensors = list(self.switch.active.sensors)
        self.odometer = Odometer(robot.has_steering or self._estimator_flag)
        self.wheels = WheelRow(robot.n_wheels, tuple(dict.fromkeys(
            c for m in self.switch.candidates for c in getattr(m.classifier, "raw_columns", ()) or ())))
        self.n = robot.n_wheels
        #: why measured slip is not observable ("" when it is; :meth:`set_mapped_groups`)
        self.slip_note = ""
        self.seq = 0
        self.n_estimator_errors = 0
        # wheel states and speeds of the last estimated tick (what a clock_jump tick serves with)
        self._last_states: list[str] = ["idle"] * self.n
        self._last_v_long: list[float] = [0.0] * self.n
        ids = (list(range(len(self.class_names))) if classifier is None
               else [int(c) for c in classifier.class_ids])
        hop_s = self.window_spec.online_hop_s
        self.filter = TerrainFilter(len(ids), stale_m=cfg.stale_m,
                                    **fusion_settings(hop_s, cfg.fusion, self.window_spec.window_s))
        self.policy = ServingPolicy(table, ids, self.class_names, serve_p=cfg.serve_p,
                                    max_age_s=cfg.max_age_s)
        check_members(ids, members)
        # one ring for the model and its members: the longest window; each cuts its own newest rows
        self.ring = RingBuffer(max(c.window_spec.n_samples for c in self.switch.candidates))
        self.scheduler = ClassificationScheduler(classifier, self.ring, self.filter, hop_s,
                                                 cfg.classify_lag_ticks, len(ids))
        self.scheduler.n_samples = self.window_spec.n_samples
        self.silence = SilenceWatch(self.scheduler, cfg.warn_after_m)
        if warm:
            warm_up(robot, preset)

    # ------------------------------------------------------------------ build
    @classmethod
    def from_model_dir(cls, model_dir: str | Path, *, robot: RobotSpec | None = None,
                       config: ServingConfig | None = None,
                       trusted_keys: Sequence[str | Path] | None = None) -> "Predictor":
        """Predictor for a verified model artifact ``runs/NAME`` (model, manifest, slip table).

        ``robot``: serve this robot (default the model's); ``config``: serving settings (its
        ``preset`` None: the model's); ``trusted_keys``: public keys (``KEY.pub``) one of which
        must have signed the artifact.
        """
        cfg = config or ServingConfig()
        served = load_serving_model(model_dir, robot, trusted_keys=trusted_keys, open_set=cfg.open_set)
        return cls(served.robot, served.table, served.classifier,
                   window_spec=served.window_spec, sensors=served.sensors,
                   config=replace(cfg, preset=cfg.preset or served.preset), members=served.members)

    @property
    def odometer_m(self) -> float:
        """Distance travelled (m, the EKF's body speed integrated over healthy ticks)."""
        return self.odometer.distance_m

    # ------------------------------------------------------------------ tick
    def step(self, sample: Sample | Mapping[str, Any]) -> DesiredSlip | None:
        """Process one base-rate sample (canonical column names + ``t_s``).

        Parameters
        ----------
        sample : a :class:`~terrainml.stream.tick.sample.Sample` (checked by :meth:`accept`), or a
            mapping of str keys to values, with ``t_s`` (s) a finite real number (``int``,
            ``float`` or a numpy scalar; not a bool, not a string), checked here. Values of the
            wrong type or non-finite only invalidate their sensor group
            (:mod:`terrainml.stream.tick.health`).

        Returns
        -------
        DesiredSlip, one per tick, every number finite; or None when the sample is dropped: a
        duplicate or late ``t_s`` (clock policy, :mod:`terrainml.stream.tick.clock`; counted in
        ``self.counters``). A ``t_s`` off the timeline is served as a fallback tick with
        ``fallback_reason="clock_jump"``; the K-th consistent one re-anchors the stream.

        Raises
        ------
        InvalidSample
            A ``ValueError`` (:mod:`terrainml.stream.tick.sample`), when ``sample`` is not a sample:
            not a mapping (None, a string, a list, ...), a key that is not a str, no ``t_s``, or a
            ``t_s`` that is not a real number (a string, a bool, None) or not finite (NaN, inf,
            an int beyond float range). It is counted first (``bad_time`` for the ``t_s`` cases,
            ``not_a_sample`` otherwise) and the predictor's state is otherwise unchanged. It is
            the only exception ``step`` raises: estimator, classifier and policy failures are
            served as fallback ticks.
        """
        t_start = time.perf_counter()
        checked = self.accept(sample)
        t = checked.t_s
        verdict = self.clock.check(t)
        if verdict == JUMP:
            return self._clock_jump_tick(t, t_start)
        if verdict == REANCHOR:
            self._restart()
        elif verdict != ACCEPT:
            return None
        clean, fresh = self.health.sanitise(checked.columns)  # type: ignore[arg-type]
        healthy, silent = self.health.update(t, fresh)
        if self.switch.has_members:  # the best of the model and its members whose groups are fresh
            chosen = self.switch.choose(silent)
            if chosen is not None:
                self._serve_with(chosen, silent, t)
            healthy = self.switch.healthy(silent)
            self.switch.ticks[self.switch.active.name] += 1

        row = self._estimate(clean)
        est_ok = healthy and row is not None and (row.estimator_ok or not self._estimator_flag)
        wheels = None
        if row is not None:
            row = self.wheels.complete(row, clean)  # columns the model's windows read, not the EKF's
            try:
                wheels = self.wheels.read(row)
                est_ok = wheels.finite and est_ok
            except (TypeError, ValueError) as exc:  # a row we cannot read: unhealthy tick
                self.n_estimator_errors += 1
                log.warning("estimator row unreadable at t=%.3f s: %s", t, exc)
                est_ok = False
            if not self._estimator_flag:
                # the EKF's own flag needs a fresh IMU (and camera); a model without one reads the
                # body channels of its windows as valid on the ticks healthy on its own groups
                row = row.with_flag(est_ok)
            self.ring.append(row)
        if wheels is None:   # no row, or one that cannot be read: every wheel idle
            wheels = self.wheels.idle()
        states, v_long = wheels.state, wheels.v_long_mps
        self._last_states, self._last_v_long = states, v_long
        d_m = self.odometer.advance(t, row if est_ok else None)
        if d_m is not None:  # the fusion filter ages by distance
            self.filter.predict(d_m)

        self.scheduler.tick(t, self.odometer.distance_m)

        age = None if self.scheduler.class_t is None else t - self.scheduler.class_t
        rejected = self.silence.check(t, self.odometer.distance_m) if est_ok else None
        return self._message(t, self._decide(age, est_ok, states, v_long, t, rejected_by=rejected),
                             wheels.slip, states, age, est_ok, t_start)

    def accept(self, sample: Any) -> Sample:
        """The typed :class:`Sample` of ``sample`` (a Sample as is); one that is not a sample is counted
        (``bad_time`` or ``not_a_sample``) and raises :class:`InvalidSample` (see :meth:`step`)."""
        if type(sample) is Sample:   # checked where it was made (every source)
            return sample
        try:
            return Sample.check(sample)
        except InvalidSample as exc:
            self.counters.count_invalid(exc.reason)
            raise

    def set_mapped_groups(self, groups: Sequence[str]) -> None:
        """The source feeds only these sensor groups (a live topic map's): the others are *not
        mapped*. Said once; they are no longer monitored (never a silent episode), and serving
        moves to the best of the model and its members that needs none of them. When every
        candidate needs one, nothing changes (the ticks stay unhealthy, as the group is silent)."""
        if "cam" not in groups and not self.slip_note:
            self.slip_note = "not observable: the source maps no body-velocity reference (cam group)"
            log.warning("measured slip %s; served as absent (null), odometry from raw wheel speeds", self.slip_note)
        unmapped = {g for g in self.health.monitored if g not in set(groups)} - {"wheels"}
        if not unmapped:
            return
        usable = [c for c in self.switch.candidates if not c.groups & unmapped]
        if not usable:
            log.warning("sensor group(s) %s not mapped by the source's topic map, and the model and every "
                        "member need them: ticks stay estimator_unhealthy", ", ".join(sorted(unmapped)))
            return
        for g in sorted(unmapped):
            log.warning("sensor group %r not mapped by the source's topic map (columns %s): not monitored", g,
                        ", ".join(self.health.group_cols[g]))
        self.health.monitored = [g for g in self.health.monitored if g not in unmapped]
        self.switch.candidates = usable
        if self.switch.active not in usable:
            self.switch.active = usable[0]
            self._serve_with(usable[0], [], 0.0, announce=False)
            log.warning("serving %s on sensors %s (the mapped ones)", "the model" if usable[0].name == "model"
                        else f"member {usable[0].name!r}", ",".join(usable[0].sensors))

    def _serve_with(self, c: Candidate, silent: Sequence[str], t: float, announce: bool = True) -> None:
        """Classify with the model or member ``c`` from this tick on (its groups are fresh)."""
        self.scheduler.use(c.classifier, c.window_spec.online_hop_s, c.window_spec.n_samples)
        self._estimator_flag = self._flag_groups <= c.groups
        self.odometer.lateral_observed = self.robot.has_steering or self._estimator_flag
        self.served_sensors = list(c.sensors)
        if announce:
            self.switch.announce(c, silent, t)

    def _clock_jump_tick(self, t: float, t_start: float) -> DesiredSlip:
        """A stamp off the timeline: the fallback row for the last estimated wheel states.

        The estimator, health monitor, ring buffer and classifier do not see the sample (its
        time would corrupt them); measured slip is served as 0 (not measured on this tick).
        """
        dec = self._decide(None, False, self._last_states, self._last_v_long, t, clock_jump=True)
        return self._message(t, dec, [0.0] * self.n, self._last_states, None, False, t_start)

    def safe_cap_traction(self) -> float:
        """Traction target of the safe cap served on fallback (design §10)."""
        return self.policy.safe_cap_traction()

    def _decide(self, age: float | None, est_ok: bool, states: list[str], v_long: list[float],
                t: float, clock_jump: bool = False, rejected_by: str | None = None) -> PolicyDecision:
        return self.policy.decide(self.filter, estimator_ok=est_ok,
                                  classifier_error=self.scheduler.error, age_s=age, states=states,
                                  v_long=v_long, clock_jump=clock_jump, t_s=t,
                                  rejected_by=rejected_by)

    def _message(self, t: float, dec: PolicyDecision, slips: list[float], states: list[str],
                 age: float | None, est_ok: bool, t_start: float) -> DesiredSlip:
        slip_des = [v if math.isfinite(v) else 0.0 for v in dec.slip_desired]
        msg = DesiredSlip(
            t_s=t, seq=self.seq, slip_desired=slip_des, slip_measured=slips, wheel_state=states,
            terrain_class=dec.class_id, terrain_name=dec.class_name, confidence=dec.confidence,
            class_probabilities=self._full_probs(len(self.class_names)),
            classification_age_s=-1.0 if age is None else float(age),
            fallback=dec.fallback, fallback_reason=dec.reason, estimator_ok=est_ok,
            fallback_detail=dec.detail, sensors=list(self.served_sensors), novelty=dec.novelty,
            slip_measured_note=self.slip_note,
        )
        self.seq += 1
        msg.processing_ms = (time.perf_counter() - t_start) * 1e3
        return msg

    def _full_probs(self, k: int) -> list[float]:
        out = [0.0] * k
        if self.scheduler.probs is not None:
            for cid, p in zip(self.policy.class_ids, self.scheduler.probs):
                if 0 <= cid < k:
                    out[cid] = float(p)
        return out

    def _restart(self) -> None:
        """A new timeline (clock policy): estimation, health, windows and classification start over."""
        if self._estimator_factory is not None:
            self.estimator = self._estimator_factory()
        else:
            reset = getattr(self.estimator, "reset", None)
            if callable(reset):
                reset()
        self.health.reset()
        self.ring.clear()
        self.scheduler.reset()  # a window of the old timeline: its result is never applied
        self.filter.reset()
        self.odometer.reset()
        self.policy.reset()

    # ------------------------------------------------------------------ parts
    def _estimate(self, clean: dict) -> EstimatorRow | None:
        """The EST row of the sanitised sample (typed; an injected estimator's mapping converted),
        or None when the estimator fails (counted)."""
        try:
            row = self.estimator.step(clean)
            return None if row is None else EstimatorRow.from_mapping(row)
        except Exception as exc:  # noqa: BLE001 - never crash the serving loop
            self.n_estimator_errors += 1
            if self.n_estimator_errors <= 3:
                log.warning("estimator step failed at t=%.3f s: %s", clean.get("t_s", math.nan), exc)
            return None

    def close(self) -> None:
        """Stop the background classification thread (if any)."""
        self.scheduler.close()

    def stats(self) -> dict[str, Any]:
        """Counters for the end-of-stream summary (stderr) and tests."""
        sch = self.scheduler
        return {**self.counters.as_dict(), "emitted": self.seq,
                "classifications": sch.n_classifications, "classifier_errors": sch.n_errors,
                "unsteady_windows": sch.n_unsteady, "estimator_errors": self.n_estimator_errors,
                "rejections": dict(sch.rejections), "rejected_channels": dict(sch.rejected_channels),
                "member_ticks": dict(self.switch.ticks), "member_switches": self.switch.switches,
                "distance_m": self.odometer.distance_m, "terrain_changes": self.filter.n_changes,
                "unknown_stretches": self.filter.n_unknown_stretches}
