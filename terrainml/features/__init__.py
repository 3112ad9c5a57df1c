"""Steady windows and feature sets (SYSTEM §8): :mod:`.windows`, :mod:`.sets`."""
