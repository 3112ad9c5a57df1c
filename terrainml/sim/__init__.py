"""Simulator of wheeled robots on the eight terrain classes: the embedded default (SYSTEM §6).

Physically grounded, fast (compiled kernel), seeded. Nothing in the estimation/learning chain
imports this package; it writes logs through :mod:`terrainml.io` (ROS 2 MCAP) or run tables.
"""

from terrainml.sim.scenarios import SCENARIOS, Scenario, make_scenario
from terrainml.sim.simulator import SimResult, Simulator

__all__ = ["SCENARIOS", "Scenario", "SimResult", "Simulator", "make_scenario"]
