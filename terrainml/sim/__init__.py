"""Simulator of wheeled robots on the eight terrain classes: the embedded default (design §6).

Physically grounded, fast (compiled kernel), seeded. Nothing in the estimation/learning chain
imports this package; it writes logs through :mod:`terrainml.io` (ROS 2 MCAP) or run tables.

:mod:`terrainml.sim.tracked` (with :mod:`terrainml.sim.patch_slip`) is a second, light model:
kinematic tracked robots with per-patch slip on a patch map, for the slip-map lap experiment
(design §13).

``sim`` is a leaf above the chain: it imports only io, the estimation definitions,
lookup.terramechanics, robot, schema and classes, never control, models, features, pipeline,
evaluation, experiments, stream or slipmap.
"""

from terrainml.sim.scenarios import SCENARIOS, Scenario, make_scenario
from terrainml.sim.simulator import SimResult, Simulator

__all__ = ["SCENARIOS", "Scenario", "SimResult", "Simulator", "make_scenario"]
