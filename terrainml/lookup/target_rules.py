"""The rules that keep desired-slip targets physical (design §10), checked wherever targets come
from: built from terramechanics (:mod:`terrainml.lookup.slip_targets`, violations clamped), given
directly by a catalogue (:mod:`terrainml.lookup.catalogue`, violations refused) and read back from a
table's JSON (:meth:`terrainml.lookup.table.DesiredSlipTable.from_json`, verified)."""

from __future__ import annotations

__all__ = ["MIN_TRACTION_MARGIN", "RIGID_PEAK_RANGE", "MAX_MAGNITUDE", "RIGID_CLASSES"]

MIN_TRACTION_MARGIN = 0.03                      # rule: s_T >= s_S + 0.03
RIGID_PEAK_RANGE = (0.10, 0.20)                 # rule: rigid-surface traction peaks
MAX_MAGNITUDE = 0.6                             # rule: |target| <= 0.6
RIGID_CLASSES = ("pavement", "compacted_dirt")  # tyre-road (Burckhardt) classes, design §6.1
