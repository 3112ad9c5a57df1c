"""The candidates ``terrainml train`` fits and chooses among: model names and window specs.

:func:`parse_models` reads model names (``svm``, ``cnn``, ``hgb``, ``all``, averages ``A+B``),
:func:`parse_auto_models` adds ``auto`` (:data:`AUTO_MODELS`), :func:`candidate_window_specs`
turns ``auto`` (:data:`SELECT_SPECS`) or spec names into parsed window specs. The command line
parses its options with them once; the pipeline takes the parsed result.
"""

from __future__ import annotations

from typing import Sequence

from terrainml.features.windows import WindowSpec, window_spec

__all__ = ["MODEL_KINDS", "AUTO_MODELS", "SELECT_SPECS", "parse_models", "parse_auto_models", "candidate_specs",
           "candidate_window_specs"]

#: base model kinds; ``A+B`` averages the probabilities of A and B
MODEL_KINDS = ("svm", "cnn", "hgb")
#: models tried by ``--model auto``
AUTO_MODELS = ("svm", "hgb", "svm+hgb")
#: window specs tried by ``--windows auto`` (those the data can feed)
SELECT_SPECS = ("short", "chunks", "state", "steady")


def _items(spec: str | Sequence[str]) -> list[str]:
    """The stripped, non-empty items of a comma-separated text or of a sequence."""
    return [m.strip() for m in (spec.split(",") if isinstance(spec, str) else spec) if m.strip()]


def parse_models(spec: str | Sequence[str]) -> list[str]:
    """Model names from ``svm``, ``cnn``, ``hgb``, ``all`` (svm and cnn) or ``A+B`` averages.

    ``"svm,svm+hgb"`` -> ``["svm", "svm+hgb"]``. ValueError names an unknown kind.
    """
    out: list[str] = []
    for m in _items(spec):
        names = ["svm", "cnn"] if m == "all" else [m]
        for name in names:
            parts = name.split("+")
            bad = [q for q in parts if q not in MODEL_KINDS]
            if bad or len(set(parts)) != len(parts):
                raise ValueError(f"unknown model {name!r}; expected {', '.join(MODEL_KINDS)}, all, or "
                                 "an average of distinct ones such as svm+hgb")
            if name not in out:
                out.append(name)
    if not out:
        raise ValueError("no model given")
    return out


def parse_auto_models(spec: str | Sequence[str]) -> list[str]:
    """``auto`` -> :data:`AUTO_MODELS`; ``auto,cnn`` adds the CNN; else :func:`parse_models`."""
    out: list[str] = []
    for m in _items(spec):
        out += list(AUTO_MODELS) if m == "auto" else [m]
    return parse_models(out)


def candidate_specs(names: str | Sequence[str]) -> list[str]:
    """``auto`` -> :data:`SELECT_SPECS`; else the comma-separated spec names."""
    out: list[str] = []
    for s in _items(names):
        out += list(SELECT_SPECS) if s == "auto" else [s]
    return list(dict.fromkeys(out))


def candidate_window_specs(specs: str | Sequence[str | WindowSpec]) -> list[WindowSpec]:
    """The parsed candidate window specs of ``auto``, spec names or specs already parsed, in
    order, each name once; ValueError names an unknown spec."""
    items = [specs] if isinstance(specs, str) else list(specs)
    out: dict[str, WindowSpec] = {}
    for item in items:
        parsed = [item] if isinstance(item, WindowSpec) else [window_spec(n) for n in candidate_specs(item)]
        for spec in parsed:
            out.setdefault(spec.name, spec)
    return list(out.values())
