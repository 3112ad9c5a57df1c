"""Shared simulator set-up of the control tests: a towed-load start on dry sand (design §12)."""

import numpy as np

from terrainml.classes import class_id
from terrainml.robot import load_robot
from terrainml.sim.mission_physics import TowedLoad, traction_peak
from terrainml.sim.scenarios import Scenario
from terrainml.sim.simulator import Simulator
from terrainml.sim.terrain import TerrainLayout


def towed_sand_start(seed: int, duration_s: float, load_w: float = 0.10):
    """The reference robot on uniform dry sand (draw ``seed``) towing a cart of ``load_w`` W rolling
    resistance, commanded a 0.8 m/s step at t = 0.5 s for ``duration_s``.

    Returns (simulator, robot, terrain class id, true traction-peak slip per wheel at static load).
    """
    rb = load_robot()
    w = rb.mass_kg * 9.81
    cid = class_id("dry_sand")

    def cmd(t, x=0.0, y=0.0, psi=0.0):
        return (0.8 if t >= 0.5 else 0.0), 0.0, 0.0

    towed = TowedLoad(mass_kg=80.0, crr=load_w / 0.9 * w / (80.0 * 9.81), tongue_fraction=0.1)
    sim = Simulator(Scenario("tow", duration_s, TerrainLayout.uniform(cid), cmd), rb, seed, towed=towed)
    peak = np.array([traction_peak(sim.terrain.params[0], wl, rb)[0]
                     for wl in rb.static_wheel_loads_n()])
    return sim, rb, cid, peak
