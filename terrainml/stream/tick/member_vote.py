"""Serving on the sensors that are there: which of a model's sensor members classifies.

A model folder may carry sensor members (:func:`terrainml.models.artifacts.attach_members`):
the same training on a subset of the model's sensor groups (without IMU, without currents).
:class:`MemberSwitch` holds the model and its members, best first, and on every tick picks
the first whose health groups (:mod:`terrainml.stream.tick.health`) are all fresh: the model while
every group it needs is healthy, else the best member that does without the silent ones. It
keeps the one it has when none is healthy (the tick is then unhealthy anyway). The predictor
(:mod:`terrainml.stream.tick.predictor`) classifies with the chosen one's classifier and window
spec, checks health on its groups only, and the message names its sensor groups.

All of them share one estimator, one ring buffer (as long as the longest window) and one fusion
filter: they classify the same classes, so a switch keeps the fused probabilities.
"""

from __future__ import annotations

import logging
from collections import Counter
from dataclasses import dataclass
from typing import Any, Sequence

from terrainml.features.windows import WindowSpec
from terrainml.stream.tick.health import SENSOR_TO_GROUP

log = logging.getLogger("terrainml.stream")

__all__ = ["Candidate", "MemberSwitch", "candidate", "check_members"]


@dataclass(frozen=True)
class Candidate:
    """The model or one of its members, as serving uses it.

    Attributes
    ----------
    name : ``model`` for the folder's model, else the member's name (``no_imu``, ...).
    classifier : its window classifier. window_spec : its windows.
    sensors : its sensor groups (``wheels``, ``currents``, ``imu``, ``cam``).
    groups : the health groups those need (:data:`~terrainml.stream.tick.health.SENSOR_TO_GROUP`,
        with the wheels, and the steering of a steered robot, always).
    """

    name: str
    classifier: Any
    window_spec: WindowSpec
    sensors: tuple[str, ...]
    groups: frozenset[str]


def candidate(name: str, classifier: Any, window_spec: WindowSpec, sensors: Sequence[str] | None,
              monitored: Sequence[str]) -> Candidate:
    """A :class:`Candidate` on ``sensors`` (None: every monitored group) of the health groups ``monitored``."""
    if sensors is None:
        groups = frozenset(monitored)
    else:
        wanted = {SENSOR_TO_GROUP.get(str(g), str(g)) for g in sensors} | {"wheels", "steer"}
        groups = frozenset(g for g in monitored if g in wanted)
    names = tuple(s for s, g in SENSOR_TO_GROUP.items() if g in groups)
    return Candidate(name, classifier, window_spec, names, groups)


class MemberSwitch:
    """The model and its members, best first; the one serving is :attr:`active`.

    Parameters
    ----------
    candidates : the model first, then its members best first.
    """

    def __init__(self, candidates: Sequence[Candidate]):
        if not candidates:
            raise ValueError("MemberSwitch needs the model")
        self.candidates = list(candidates)
        self.active = self.candidates[0]
        self.switches = 0
        self.ticks: Counter[str] = Counter()  # ticks served by each (only with members)

    @property
    def has_members(self) -> bool:
        return len(self.candidates) > 1

    def choose(self, silent: Sequence[str]) -> Candidate | None:
        """Make the best candidate without a silent group active; return it if it changed, else None."""
        quiet = set(silent)
        for c in self.candidates:
            if not c.groups & quiet:
                if c is self.active:
                    return None
                self.active = c
                self.switches += 1
                return c
        return None  # none is healthy: keep the one serving

    def healthy(self, silent: Sequence[str]) -> bool:
        """Whether every group the active candidate needs is fresh."""
        return not self.active.groups & set(silent)

    def announce(self, c: Candidate, silent: Sequence[str], t: float) -> None:
        """Warn that ``c`` serves from ``t`` on (the first 5 switches, then every 100th)."""
        n = self.switches
        if n <= 5 or n % 100 == 0:
            log.warning("t=%.2f s: serving %s on sensors %s%s (switch %d)", t,
                        "the model" if c.name == "model" else f"member {c.name!r}", ",".join(c.sensors),
                        f"; silent: {','.join(silent)}" if silent else "", n)


def check_members(ids: Sequence[int], members: Sequence[Any]) -> None:
    """Members (``name``, ``classifier.class_ids``) classify the model's classes: the fusion and the
    policy read one set of ids."""
    for m in members:
        own = [int(c) for c in m.classifier.class_ids]
        if own != list(ids):
            raise ValueError(f"member {m.name!r} classifies class ids {own}, the model {list(ids)}")
