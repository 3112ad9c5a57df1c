"""Traction control (design §12): the per-wheel slip PID of thesis §8.3, the slip limiter and the
controllers.

:mod:`terrainml.control.pid` holds :class:`~terrainml.control.pid.SlipPID`, which turns the
per-wheel slip error into a correction of the low-level wheel-speed command (eq. 8.3);
:mod:`terrainml.control.traction` holds :class:`~terrainml.control.traction.SlipController`
(measured sample -> correction, with the online estimator or predictor);
:mod:`terrainml.control.slip_limiter` the per-wheel limiter that acts from rest to cruise,
:mod:`terrainml.control.cap_refiner` the online refinement of its cap from thrust-slip data and
:mod:`terrainml.control.baselines` the mission-suite policies. Nothing here imports the
simulator; the simulated closed-loop experiment is :mod:`terrainml.experiments.closed_loop`.
"""

from terrainml.control.cap_refiner import CapRefiner, CapRefinerConfig
from terrainml.control.pid import PIDStep, SlipPID, SlipPIDConfig
from terrainml.control.slip_limiter import LimiterStep, SlipLimiter, SlipLimiterConfig
from terrainml.control.traction import SlipController, tuned_config

__all__ = ["CapRefiner", "CapRefinerConfig", "LimiterStep", "PIDStep", "SlipController",
           "SlipLimiter", "SlipLimiterConfig", "SlipPID", "SlipPIDConfig", "tuned_config"]
