"""What a sample is, and the one error raised for anything that is not one (design §11).

A sample is a mapping of ``str`` keys to values with a ``t_s`` (s) that is a real number
(``int``, ``float`` or a numpy scalar, not ``bool``) with a finite float value; any other key is a
canonical run-table column (:mod:`terrainml.schema`) or an extra (values of the wrong type or
non-finite only invalidate their sensor group, :mod:`terrainml.stream.tick.health`).
:func:`check_sample` is the single definition: :meth:`Sample.check` turns a mapping that passes it
into the typed :class:`Sample` a tick and the sinks take. Every source of
:mod:`terrainml.stream.transports` checks each sample once, where it makes it, and yields it typed
(:func:`typed_samples`; one that fails is counted as malformed and skipped);
:meth:`terrainml.stream.tick.predictor.Predictor.step` checks a plain mapping (the Python API) and
raises its :class:`InvalidSample`.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any, Callable

#: reasons an :class:`InvalidSample` carries (``InvalidSample.reason``)
INVALID_REASONS: tuple[str, ...] = (
    "not_a_mapping",  # None, a string, a list, a number, ...
    "bad_key",        # a key that is not a str
    "no_t_s",         # no "t_s" key
    "bad_t_s",        # t_s is not a real number (a string, a bool, None, a list, ...)
    "t_s_not_finite",  # t_s is NaN, +-inf, or an integer too large for a float
)

#: the reasons about ``t_s`` (counted as ``bad_time``; the others as ``not_a_sample``)
TIME_REASONS: tuple[str, ...] = ("no_t_s", "bad_t_s", "t_s_not_finite")


class InvalidSample(ValueError):
    """The argument of ``Predictor.step`` is not a sample; ``reason`` is one of :data:`INVALID_REASONS`."""

    def __init__(self, reason: str, detail: str):
        super().__init__(f"invalid sample ({reason}): {detail}")
        self.reason = reason


def _short(v: Any) -> str:
    text = repr(v) if not isinstance(v, int) or abs(v) < 10**30 else f"<int of {v.bit_length()} bits>"
    return text if len(text) <= 60 else text[:57] + "..."


def check_sample(sample: Any) -> float:
    """Validate ``sample``; return its ``t_s`` as a finite float, or raise :class:`InvalidSample`."""
    if not isinstance(sample, Mapping):
        raise InvalidSample("not_a_mapping", f"expected a mapping, got {type(sample).__name__}")
    for k in sample:
        if not isinstance(k, str):
            raise InvalidSample("bad_key", f"key {_short(k)} is not a str")
    if "t_s" not in sample:
        raise InvalidSample("no_t_s", "no 't_s' key")
    t = sample["t_s"]
    if isinstance(t, bool) or not isinstance(t, numbers.Real):
        raise InvalidSample("bad_t_s", f"t_s {_short(t)} is not a number")
    try:
        t_s = float(t)
    except (OverflowError, ValueError, TypeError):  # int beyond float range, exotic Real
        raise InvalidSample("t_s_not_finite", f"t_s {_short(t)} does not fit a float") from None
    if not math.isfinite(t_s):
        raise InvalidSample("t_s_not_finite", f"t_s is {t_s}")
    return t_s


@dataclass(frozen=True, slots=True)
class Sample:
    """One checked base-rate sample: what a tick serves from, and what sinks are handed with
    its message.

    Attributes
    ----------
    t_s : s, finite.
    columns : the sample as the source gave it, by canonical column name (``t_s`` included;
        extras such as a ROS 2 source's stamp origin too). Read only.
    """

    t_s: float
    columns: Mapping[str, Any]

    @classmethod
    def check(cls, sample: Any) -> "Sample":
        """The typed sample of a mapping that passes :func:`check_sample` (else :class:`InvalidSample`)."""
        return cls(check_sample(sample), sample)


def typed_samples(samples: Iterable[Any],
                  count_invalid: Callable[[str, Any], None] | None = None) -> Iterator[Sample]:
    """The typed :class:`Sample` of each of ``samples`` (mappings a source made), checked once.

    One that is not a sample is handed to ``count_invalid(reason, sample)`` (``reason`` one of
    :data:`INVALID_REASONS`) and skipped: a source never raises for it.
    """
    for raw in samples:
        try:
            t_s = check_sample(raw)
        except InvalidSample as exc:
            if count_invalid is not None:
                count_invalid(exc.reason, raw)
            continue
        yield Sample(t_s, raw)


#: the sample of a tick that has none to hand over (a sink called without one)
NO_SAMPLE = Sample(float("nan"), {})
