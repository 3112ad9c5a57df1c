"""The simulator: vehicle + terrain + low-level control + sensors, with a closed-loop hook.

Example
-------
>>> from terrainml.sim import Simulator, make_scenario
>>> sim = Simulator(make_scenario("straight", "short_grass", duration_s=10.0), seed=1)
>>> result = sim.run()
>>> result.mean_true_slip(5.0, 10.0).round(2)          # doctest: +SKIP

Closed loop: ``sim.run(controller=f)`` calls ``f(sample)`` every control tick (100 Hz) with the
current *measured* sample (a dict of canonical run-table columns, design §5, plus ``t_s``); ``f``
returns per-wheel wheel-speed command offsets (rad/s, shape (N,)) that are added to the inverse
kinematics' set-points (thesis eq. 8.3) or ``None``.

Missions (API in :mod:`terrainml.sim.mission_physics`): ``towed=TowedLoad(...)``,
``tool_draft_n``, :meth:`Simulator.set_payload_kg`, :meth:`Simulator.set_tool_draft_n`, a graded
layout (``TerrainLayout.with_grade``), battery energy and the new log columns.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from terrainml.robot import RobotSpec, load_robot
from terrainml.sim import physics as ph
from terrainml.sim.control import DriveGains, _ik_kernel
from terrainml.sim.mission_physics import BELLY_MU, BELLY_RAMP_M, TowedLoad, cart_crr_per_class, dig_params
from terrainml.sim.scenarios import Scenario
from terrainml.sim.sensors import LOG_RATE_HZ, SensorConfig, SensorModel
from terrainml.sim.terrain import ALPHA_GRID, LOAD_FACTORS, TerrainRealisation, realise
from terrainml.estimation.dynamic_state import manoeuvre_accel
from terrainml.sim.truth import slip_sae, wheel_states
from terrainml.schema import wheel_col

CONTROL_RATE_HZ = 100.0
Controller = Callable[[dict], "np.ndarray | None"]


@dataclass
class SimResult:
    """Truth log (200 Hz), commands (100 Hz), sensors and run summary of one simulated run."""

    robot: RobotSpec
    scenario: Scenario
    terrain: TerrainRealisation
    sensors: SensorModel
    log: np.ndarray                 # (n_rows, n_cols) see terrainml.sim.physics
    cmd: np.ndarray                 # (n_ticks, 3) commanded twist at 100 Hz (tick k at t = k/100)
    omega_cmd: np.ndarray           # (n_ticks, N) wheel speed set-points incl. controller offsets
    seed: int
    energy_j: float
    distance_m: float
    stuck_events: int
    summary: dict = field(default_factory=dict)

    @property
    def battery_energy_j(self) -> float:
        """Energy drawn from the battery (J), regeneration counted negative."""
        return self.summary["battery_energy_j"]

    @property
    def battery_energy_noregen_j(self) -> float:
        """Energy drawn from the battery (J) without regeneration (braking energy dumped)."""
        return self.summary["battery_energy_noregen_j"]

    @property
    def copper_loss_j(self) -> float:
        return self.summary["copper_loss_j"]

    @property
    def slip_work_j(self) -> float:
        """Sum over wheels of the integral of |H (omega R - v_long)| dt (J)."""
        return self.summary["slip_work_j"]

    @property
    def drawbar_work_j(self) -> float:
        """Work done on the towed cart and tool: integral of hitch force x speed (J)."""
        return self.summary["drawbar_work_j"]

    def body_col(self, name: str) -> np.ndarray:
        """(n_rows,) body log column by name (``terrainml.sim.physics.LOG_COLS``)."""
        return self.log[:, ph.LOG_COLS.index(name)]

    # ------------------------------------------------------------------ truth views
    @property
    def n_wheels(self) -> int:
        return self.robot.n_wheels

    def wblock(self, name: str) -> np.ndarray:
        n = self.n_wheels
        j = ph.WLOG.index(name)
        return self.log[:, ph.N_LOG_BODY + j * n: ph.N_LOG_BODY + (j + 1) * n]

    @property
    def t_s(self) -> np.ndarray:
        return self.log[:, ph.L_T]

    def true_slip(self) -> np.ndarray:
        """(n_rows, N) design §7.1 slip of true wheel speed vs true wheel-centre longitudinal velocity."""
        return slip_sae(self.wblock("omega") * self.robot.wheel_radius_m, self.wblock("v_long"))

    def wheel_long_accel(self) -> np.ndarray:
        """(n_rows, N) inertial acceleration of each wheel centre along its heading (m/s^2)."""
        lg = self.log
        # origin acceleration -> wheel point: a_i = a_o + rdot k x d_i - r^2 d_i  (d_i from origin)
        wx = np.array([w.x_m for w in self.robot.wheels])
        wy = np.array([w.y_m for w in self.robot.wheels])
        r = lg[:, ph.L_R][:, None]
        rd = lg[:, ph.L_RDOT][:, None]
        ax = lg[:, ph.L_AX][:, None] - rd * wy - r * r * wx
        ay = lg[:, ph.L_AY][:, None] + rd * wx - r * r * wy
        d = self.wblock("delta")
        return ax * np.cos(d) + ay * np.sin(d)

    def true_states(self, rows: np.ndarray | None = None) -> np.ndarray:
        """(n, N) design §7.2 state codes from true acceleration (rows: default every 100 Hz row)."""
        rows = np.arange(0, len(self.log), 2) if rows is None else rows
        vl = self.wblock("v_long")[rows]
        # the same manoeuvre filter the estimator applies (vibration out; design §7.2 departure)
        a_long = manoeuvre_accel(self.t_s[rows], self.wheel_long_accel()[rows])
        return wheel_states(self.t_s[rows], a_long * vl, vl)

    def mean_true_slip(self, t0: float, t1: float) -> np.ndarray:
        m = (self.t_s >= t0) & (self.t_s <= t1)
        return self.true_slip()[m].mean(axis=0)

    def class_under_robot(self, rows: np.ndarray | None = None) -> np.ndarray:
        rows = np.arange(len(self.log)) if rows is None else rows
        return self.terrain.layout.class_at(self.log[rows, ph.L_X], self.log[rows, ph.L_Y])


def _vehicle_pack(rb: RobotSpec, wx: np.ndarray, wy: np.ndarray, gains: DriveGains, dt: float) -> tuple:
    """The physics kernel's vehicle pack (:class:`terrainml.sim.physics.Vehicle`) of a robot spec."""
    a = np.vstack([np.ones(rb.n_wheels), wx, wy])
    motor = rb.motor_or_default
    return tuple(ph.Vehicle(
        wx=wx, wy=wy, xc=float(rb.com_x_m), yc=float(rb.com_y_m), mass=float(rb.mass_kg),
        iz=float(rb.yaw_inertia_kgm2), rw=float(rb.wheel_radius_m), jw=float(rb.wheel_inertia_kgm2),
        hcg=float(rb.com_height_m), load_pinv=np.ascontiguousarray(np.linalg.pinv(a)),
        kp=float(gains.kp_nms_per_rad), ki=float(gains.ki_nm_per_rad), tau_max=float(rb.max_wheel_torque_nm),
        steer_rate_max=float(rb.steering_rate_max_radps), steer_deadband=float(rb.steering_deadband_rad),
        steer_tau=float(gains.steer_tau_s), omega_lag_tau=float(gains.omega_lag_tau_s), dt=dt,
        kt=float(rb.torque_constant_nm_per_a), r_ph=float(motor.phase_resistance_ohm),
        eta_drv=float(motor.driver_efficiency), eta_regen=float(motor.regen_efficiency),
        clearance=float(rb.ground_clearance_or_default_m), belly_mu=BELLY_MU, belly_ramp=BELLY_RAMP_M))


def _ground_pack(ter, lay, towed: TowedLoad | None) -> tuple:
    """The physics kernel's ground pack (:class:`terrainml.sim.physics.Ground`): force tables per
    cell, layout grid, grades, sinkage and cart rolling resistance per class."""
    classes = lay.grid.reshape(-1).astype(np.int64)
    digs = [dig_params(int(c)) for c in classes]
    slope_x, slope_y = lay.slopes()
    crr_cls = cart_crr_per_class(towed.crr if towed is not None else 0.0)
    return tuple(ph.Ground(
        h_tab=ter.h_coef, r_tab=ter.r_coef, y_tab=ter.y_coef, hmax_tab=ter.hmax_coef,
        w_ref=float(ter.load_ref_n), load_grid=LOAD_FACTORS, alpha_lo=float(ALPHA_GRID[0]),
        alpha_step=float(ALPHA_GRID[1] - ALPHA_GRID[0]), rough_amp=ter.rough_amp_m,
        rough_k=ter.rough_k_radpm, rough_phase=ter.rough_phase,
        lay_grid=np.ascontiguousarray(lay.grid.astype(np.int64)), lay_cell=float(lay.cell_m),
        lay_ox=float(lay.origin_xy_m[0]), lay_oy=float(lay.origin_xy_m[1]),
        grad_x=np.tan(slope_x).reshape(-1), grad_y=np.tan(slope_y).reshape(-1),
        len_tab=np.ascontiguousarray(ter.len_tab_m), z_tab=np.ascontiguousarray(ter.z_tab_m),
        free_slip=np.array([p.free_slip for p in ter.params], float),
        dig_k=np.array([d.kappa for d in digs]), dig_relax=np.array([d.relax_m for d in digs]),
        dig_cap=np.array([d.cap_m for d in digs]), cart_crr=crr_cls[classes]))


class Simulator:
    """One simulated run. Build with a :class:`Scenario`; call :meth:`run` (or :meth:`step` per tick).

    Parameters
    ----------
    scenario : what to drive where (:func:`terrainml.sim.scenarios.make_scenario`).
    robot : RobotSpec (reference robot if None).
    seed : int or ``numpy.random.SeedSequence``; everything random derives from it.
    spread : terrain parameter spread around the class nominal (design §6.1, ±15%).
    params : explicit TerrainParams per layout cell (overrides the draw; e.g. nominal for calibration).
    dt_s : physics step (s), at most 1/500.
    towed : a cart pulled at a hitch (:class:`~terrainml.sim.mission_physics.TowedLoad`) or None.
    tool_draft_n : draft of a soil-engaging tool at the hitch (N, opposes the motion).
    """

    def __init__(self, scenario: Scenario, robot: RobotSpec | str | None = None, seed=0, *,
                 spread: float = 0.15, params=None, dt_s: float = 0.001, gains: DriveGains = DriveGains(),
                 sensor_config: SensorConfig = SensorConfig(), towed: TowedLoad | None = None,
                 tool_draft_n: float = 0.0):
        if dt_s > 1.0 / 500.0:
            raise ValueError(f"dt_s must be <= 0.002 s (>= 500 Hz), got {dt_s}")
        self.robot = load_robot(robot)
        self.scenario = scenario
        self.seed_seq = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(int(seed))
        self.seed = int(self.seed_seq.entropy) if not isinstance(seed, np.random.SeedSequence) else -1
        ss_terrain, ss_sensor = self.seed_seq.spawn(2)
        self.terrain = realise(scenario.layout, self.robot, np.random.default_rng(ss_terrain), spread, params)
        rb = self.robot
        n = rb.n_wheels
        self.dt = float(dt_s)
        self.n_sub = int(round(1.0 / CONTROL_RATE_HZ / self.dt))
        self.log_every = int(round(1.0 / LOG_RATE_HZ / self.dt))
        if self.n_sub * self.dt * CONTROL_RATE_HZ != 1.0 and abs(self.n_sub * self.dt * CONTROL_RATE_HZ - 1) > 1e-9:
            raise ValueError("dt_s must divide the 10 ms control period")
        self.n_ticks = int(round(scenario.duration_s * CONTROL_RATE_HZ))
        self.n_rows = self.n_ticks * 2 + 1
        self.sensors = SensorModel(self.n_rows, n, np.random.default_rng(ss_sensor), sensor_config)
        self.wx = np.array([w.x_m for w in rb.wheels], float)
        self.wy = np.array([w.y_m for w in rb.wheels], float)
        self.steerable = np.array([w.steerable for w in rb.wheels], bool)
        self._steer_i = self.steerable.astype(np.int64)
        self.static_loads = np.array(rb.static_wheel_loads_n())
        self.towed = towed
        # the physics kernel's packs, as plain tuples (see terrainml.sim.physics)
        self._vehicle = _vehicle_pack(rb, self.wx, self.wy, gains, self.dt)
        self._ground = _ground_pack(self.terrain, scenario.layout, towed)
        # state
        self.body = np.zeros(ph.N_BODY)
        self.wheel = np.zeros((ph.N_WROWS, n))
        self.wheel[ph.W_LOAD] = self.static_loads
        self.acc = np.zeros(len(ph.ACC))
        self.log = np.zeros((self.n_rows, ph.N_LOG_BODY + len(ph.WLOG) * n))
        self.ext = np.zeros(len(ph.EXT))
        if towed is not None:
            self.ext[ph.E_TONGUE] = towed.tongue_fraction
            self.ext[[ph.E_HX, ph.E_HY, ph.E_HZ]] = towed.hitch_xyz_m
        else:
            self.ext[[ph.E_HX, ph.E_HY]] = (rb.com_x_m, rb.com_y_m)
        self.set_payload_kg(towed.payload_kg if towed is not None else 0.0)
        self.set_tool_draft_n(tool_draft_n)
        self._state = tuple(ph.SimState(self.body, self.wheel, self.acc, self.log, self.ext))
        self._init_log_row()
        self.log_row = 1
        self.tick = 0
        self.cmd = np.zeros((self.n_ticks, 3))
        self.omega_cmd = np.zeros((self.n_ticks, n))
        self.delta_cmd = np.zeros(n)
        self._stuck_time = 0.0
        self.stuck_events = 0
        self._stuck_flag = False
        self._mount = (rb.camera.x_m, rb.camera.y_m) if rb.camera is not None else (0.0, 0.0)

    # ------------------------------------------------------------------ mission loads
    @property
    def payload_kg(self) -> float:
        return self._payload_kg

    def set_payload_kg(self, payload_kg: float) -> None:
        """Cart payload (kg) from the next step on (needs ``towed``; 0 without one)."""
        if payload_kg < 0:
            raise ValueError(f"payload_kg must be >= 0, got {payload_kg}")
        if self.towed is None and payload_kg != 0:
            raise ValueError("set_payload_kg needs a towed load (Simulator(..., towed=TowedLoad(...)))")
        self._payload_kg = float(payload_kg)
        self.ext[ph.E_MC] = (self.towed.mass_kg if self.towed is not None else 0.0) + self._payload_kg

    @property
    def tool_draft_n(self) -> float:
        return float(self.ext[ph.E_DRAFT])

    def set_tool_draft_n(self, draft_n: float) -> None:
        """Draft of a soil-engaging tool (N, >= 0) at the hitch, from the next step on."""
        if not draft_n >= 0:
            raise ValueError(f"tool_draft_n must be >= 0, got {draft_n}")
        self.ext[ph.E_DRAFT] = float(draft_n)

    def _init_log_row(self) -> None:
        n = self.robot.n_wheels
        base = ph.N_LOG_BODY
        self.log[0, base + 6 * n: base + 7 * n] = self.static_loads
        self.log[0, base + 7 * n: base + 8 * n] = self.scenario.layout.cell_index(
            self.wx, self.wy)
        z0 = self.terrain.z_tab_m[self.log[0, base + 7 * n: base + 8 * n].astype(int), :,
                                  self.terrain.z_tab_m.shape[2] // 2]
        lf = self.static_loads / self.terrain.load_ref_n
        for i in range(n):                                  # static sinkage at the static load
            zi = np.interp(lf[i], LOAD_FACTORS, z0[i])
            self.log[0, base + 8 * n + i] = self.log[0, base + 9 * n + i] = zi
            self.wheel[ph.W_Z, i] = zi
        sx, _ = self.scenario.layout.grade_at(0.0, 0.0)
        self.log[0, ph.L_PITCH] = float(sx)

    # ------------------------------------------------------------------ stepping
    @property
    def t_s(self) -> float:
        return self.tick / CONTROL_RATE_HZ

    @property
    def done(self) -> bool:
        return self.tick >= self.n_ticks

    def measured_sample(self, row: int | None = None) -> dict:
        """Measured sensor sample (canonical column names) at a 100 Hz log row (default: latest)."""
        row = self.log_row - 1 if row is None else row
        row = row - (row % 2)
        return sample_dict(self, self.log, np.array([row]), self.robot)

    def step(self, controller: Controller | None = None) -> None:
        """Advance one control tick (10 ms): command, inverse kinematics, controller, physics."""
        if self.done:
            raise RuntimeError("simulation finished")
        k = self.tick
        b = self.body
        vx, vy, r = self.scenario.command(self.t_s, b[ph.B_X], b[ph.B_Y], b[ph.B_PSI])
        omega = np.empty(self.robot.n_wheels)
        delta = np.empty(self.robot.n_wheels)
        _ik_kernel(vx, vy, r, self.wx, self.wy, self.robot.wheel_radius_m, self.delta_cmd, self._steer_i,
                   1e-3, omega, delta)
        if controller is not None:
            off = controller(self.measured_sample())
            if off is not None:
                omega = omega + np.asarray(off, dtype=float).reshape(-1)
        self.delta_cmd = delta
        self.cmd[k] = (vx, vy, r)
        self.omega_cmd[k] = omega
        self.log_row = ph.run_substeps(self._vehicle, self._ground, self._state, self.n_sub, omega, delta,
                                       self.log_row, self.log_every)
        self._update_stuck()
        self.tick += 1

    def _update_stuck(self) -> None:
        """A stuck event: commanded >= 0.2 m/s but true speed < 20% of it for 1 s."""
        c = self.cmd[self.tick]
        vc = math.hypot(c[0], c[1])
        row = self.log[self.log_row - 1]
        if vc >= 0.2 and math.hypot(row[ph.L_VX], row[ph.L_VY]) < 0.2 * vc:
            self._stuck_time += 1.0 / CONTROL_RATE_HZ
        else:
            self._stuck_time = 0.0
            self._stuck_flag = False
        if not self._stuck_flag and self._stuck_time >= 1.0:
            self.stuck_events += 1
            self._stuck_flag = True

    def run(self, controller: Controller | None = None, progress: Callable[[float], None] | None = None) -> SimResult:
        """Run to the scenario's end; ``controller`` as in the module docstring."""
        while not self.done:
            self.step(controller)
            if progress is not None and self.tick % 500 == 0:
                progress(self.tick / self.n_ticks)
        return self.result()

    def result(self) -> SimResult:
        rows = self.log_row
        a = self.acc
        return SimResult(self.robot, self.scenario, self.terrain, self.sensors, self.log[:rows].copy(),
                         self.cmd[:self.tick].copy(), self.omega_cmd[:self.tick].copy(), self.seed,
                         float(a[ph.A_EMECH]), float(a[ph.A_DIST]), int(self.stuck_events),
                         {"energy_j": float(a[ph.A_EMECH]), "distance_m": float(a[ph.A_DIST]),
                          "stuck_events": int(self.stuck_events), "duration_s": float(a[ph.A_TIME]),
                          "battery_energy_j": float(a[ph.A_BATT]),
                          "battery_energy_noregen_j": float(a[ph.A_BATT_NR]),
                          "copper_loss_j": float(a[ph.A_CU]), "slip_work_j": float(a[ph.A_SLIPW]),
                          "drawbar_work_j": float(a[ph.A_DPW])})


def sample_dict(sim_or_result, log: np.ndarray, rows: np.ndarray, robot: RobotSpec) -> dict:
    """Measured sample(s) at 100 Hz log ``rows`` as canonical columns (arrays when len(rows) > 1)."""
    sens: SensorModel = sim_or_result.sensors
    n = robot.n_wheels
    one = len(rows) == 1
    out: dict = {"t_s": log[rows, ph.L_T]}
    om = sens.wheel_omega(log, rows, n)
    st = sens.steer(log, rows, n)
    cur = sens.current(log, rows, n, robot.torque_constant_nm_per_a)
    for i in range(n):
        out[wheel_col("omega", i + 1)] = om[:, i]
        out[wheel_col("steer", i + 1)] = st[:, i]
        out[wheel_col("current", i + 1)] = cur[:, i]
    acc, gyro = sens.imu(log, rows)
    out["imu_ax_mps2"], out["imu_ay_mps2"], out["imu_az_mps2"] = acc[:, 0], acc[:, 1], acc[:, 2]
    out["imu_yaw_rate_radps"] = gyro[:, 2]
    if robot.camera is not None:
        mount = (robot.camera.x_m, robot.camera.y_m)
        vmx, vmy, rate, yaw, conf = sens.cam_body(log, rows, mount)
        out.update(cam_vx_mps=vmx, cam_vy_mps=vmy, cam_yaw_rate_radps=rate, cam_yaw_rad=yaw,
                   cam_confidence=conf)
    if one:
        out = {k: float(v[0]) for k, v in out.items()}
    return out
