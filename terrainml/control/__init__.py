"""Traction control (SYSTEM §12): the per-wheel slip PID of thesis §8.3.

:mod:`terrainml.control.pid` holds :class:`~terrainml.control.pid.SlipPID`, which turns the
per-wheel slip error into a correction of the low-level wheel-speed command (eq. 8.3).
"""

from terrainml.control.pid import PIDStep, SlipPID, SlipPIDConfig

__all__ = ["PIDStep", "SlipPID", "SlipPIDConfig"]
