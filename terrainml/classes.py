"""The eight terrain-stiffness classes (design §6.1), ordered stiff to soft.

Ids are stable and part of every artifact. Other datasets (e.g. BorealTC) bring their own
class sets; artifacts store the classes they were trained on, so this list is only the default.
"""

from __future__ import annotations

TERRAIN_CLASSES: tuple[str, ...] = (
    "pavement",
    "compacted_dirt",
    "short_grass",
    "gravel_on_firm_soil",
    "tall_damp_grass",
    "tilled_loam",
    "dry_sand",
    "wet_mud",
)
N_CLASSES = len(TERRAIN_CLASSES)


def class_id(name_or_id: str | int) -> int:
    """Return the class id for a class name or id; raise ValueError listing valid names."""
    if isinstance(name_or_id, (int,)) and not isinstance(name_or_id, bool):
        if 0 <= name_or_id < N_CLASSES:
            return int(name_or_id)
        raise ValueError(f"terrain class id {name_or_id} out of range 0..{N_CLASSES - 1}")
    name = str(name_or_id).strip()
    if name.isdigit():
        return class_id(int(name))
    try:
        return TERRAIN_CLASSES.index(name)
    except ValueError:
        raise ValueError(
            f"unknown terrain class {name!r}; expected one of: {', '.join(TERRAIN_CLASSES)}"
        ) from None


def class_name(cid: int) -> str:
    """Return the class name for an id."""
    return TERRAIN_CLASSES[class_id(int(cid))]
