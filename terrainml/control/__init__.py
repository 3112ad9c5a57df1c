"""Traction control (design §12): the per-wheel slip PID of thesis §8.3 and the controller.

:mod:`terrainml.control.pid` holds :class:`~terrainml.control.pid.SlipPID`, which turns the
per-wheel slip error into a correction of the low-level wheel-speed command (eq. 8.3);
:mod:`terrainml.control.traction` holds :class:`~terrainml.control.traction.SlipController`
(measured sample -> correction, with the online estimator or predictor). Nothing here imports
the simulator; the simulated closed-loop experiment is :mod:`terrainml.experiments.closed_loop`.
"""

from terrainml.control.pid import PIDStep, SlipPID, SlipPIDConfig
from terrainml.control.traction import SlipController, tuned_config

__all__ = ["PIDStep", "SlipController", "SlipPID", "SlipPIDConfig", "tuned_config"]
