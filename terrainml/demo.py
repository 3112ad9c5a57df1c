"""The demo: the chain on the embedded default, growing with each stage that exists."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from rich.console import Console

from terrainml.io.mcap_writer import RosMcapWriter
from terrainml.robot import load_robot


def run_demo(out: Path, seed: int = 0, console: Console | None = None) -> None:
    console = console or Console(stderr=True)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    robot = load_robot()
    rng = np.random.default_rng(seed)
    path = out / "handmade.mcap"
    with RosMcapWriter(path, robot.n_wheels) as w:
        for k in range(500):
            t = k * 0.01
            w.write_imu(t, (rng.normal(0, 0.05), 0.0, 9.81), (0.0, 0.0, rng.normal(0, 0.01)))
            w.write_wheel_joints(t, [1.0 / robot.wheel_radius_m] * robot.n_wheels, [0.0] * robot.n_wheels)
            w.write_motor_current(t, [1.0] * robot.n_wheels)
    console.print(f"[green]wrote[/] {path}")
