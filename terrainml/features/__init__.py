"""Steady windows and feature sets (design §8): :mod:`.windows`, :mod:`.sets` (the reference
robot's features) and :mod:`.side_channel` (a skid-steer robot without camera or steering)."""
