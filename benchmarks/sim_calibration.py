"""Simulator calibration and acceptance figures: ``run(quick) -> str`` (Markdown).

Also the record of how the free parameters of :mod:`terrainml.lookup.terramechanics` were
calibrated: :func:`calibrate_class` re-derives a class's shear modulus K and free slip s_f by least
squares so that (a) the root of mu_net(s) = 0 on the reference robot equals the design §6.1 target
and (b) the traction peak of mu_net sits at the chosen peak slip (``CALIBRATION_TARGETS``).

Run: ``.venv/bin/python -m benchmarks.sim_calibration`` (prints the section) or through
``benchmarks/bench_sim.py`` (``make bench``).
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from terrainml.classes import TERRAIN_CLASSES
from terrainml.lookup import terramechanics as tm
from terrainml.robot import load_robot

# design §6.1 steady-slip ranges at 1 m/s (tilled_loam / dry_sand "about": ±0.03 used)
TARGET_RANGES = {
    "pavement": (-0.01, 0.01), "compacted_dirt": (0.02, 0.05), "short_grass": (0.116, 0.135),
    "gravel_on_firm_soil": (0.122, 0.146), "tall_damp_grass": (0.16, 0.22), "tilled_loam": (0.17, 0.23),
    "dry_sand": (0.27, 0.33), "wet_mud": (0.35, 0.5),
}
# (steady-slip target, traction-peak slip, Wong residual ratio K_r) used to calibrate K and s_f
CALIBRATION_TARGETS = {
    "compacted_dirt": (0.035, 0.14, 0.75),
    "short_grass": (0.1255, 0.22, 0.8),
    "gravel_on_firm_soil": (0.134, 0.26, 0.8),
    "tall_damp_grass": (0.19, 0.30, 0.8),
    "tilled_loam": (0.20, 0.32, 0.85),
    "dry_sand": (0.30, 0.42, 0.7),
    "wet_mud": (0.42, 0.53, 0.7),
}


def _peak(p, w, robot, s=np.linspace(0.0, 0.8, 3201)):
    mu = tm.net_traction_coefficient(p, w, s, robot)
    i = int(np.argmax(mu))
    return float(s[i]), float(mu[i])


def calibrate_class(name: str, robot=None) -> tm.TerrainParams:
    """Re-derive (K, s_f) of a soil class from :data:`CALIBRATION_TARGETS` (least squares)."""
    from scipy.optimize import least_squares

    robot = load_robot(robot)
    w = robot.static_wheel_loads_n()[0]
    ss_t, pk_t, kr = CALIBRATION_TARGETS[name]
    p0 = replace(tm.nominal_params(name), residual_ratio=kr)

    def res(x):
        p = replace(p0, shear_modulus_m=float(x[0]), free_slip=float(x[1]))
        ss = tm.steady_slip(p, w, robot)
        return [((ss if np.isfinite(ss) else 1.0) - ss_t) * 10.0, (_peak(p, w, robot)[0] - pk_t) * 3.0]

    best = None
    for k0 in (0.005, 0.01, 0.02):
        for f0 in (0.0, 0.5 * ss_t, 0.9 * ss_t):
            r = least_squares(res, [k0, f0], bounds=([0.001, 0.0], [0.2, 0.6]), diff_step=1e-3)
            if best is None or r.cost < best.cost:
                best = r
    return replace(p0, shear_modulus_m=float(best.x[0]), free_slip=float(best.x[1]))


def _table(headers, rows) -> str:
    out = ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
    out += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(out)


def run(quick: bool = False) -> str:
    from terrainml.sim import Simulator, make_scenario
    from terrainml.sim.generate import simulate
    from terrainml.sim.simulator import sample_dict

    robot = load_robot()
    w = robot.static_wheel_loads_n()[0]
    n_real = 3 if quick else 10
    lines = ["## Simulator calibration and acceptance (`benchmarks/sim_calibration.py`)", "",
             "Protocol (thesis §7.2.3): straight run, 1 m/s^2 start to 1 m/s, mean **true** slip over the "
             "last 15 s of 30 s, reference robot (80 kg, 3 wheels, equal loads 261.6 N). `root` is the zero of "
             "mu_net(s) from `terramechanics` (what the lookup uses); `sim nominal` the simulated run with the "
             f"class's nominal parameters; `sim realisations` mean ± std over {n_real} runs with ±15% parameter "
             "spread (classes overlap, as real soils do). Peak = largest true slip in the first 3 s.", ""]
    rows, sim_means, energy = [], [], {}
    t0 = time.perf_counter()
    for cid, name in enumerate(TERRAIN_CLASSES):
        lo, hi = TARGET_RANGES[name]
        p = tm.nominal_params(cid)
        root = tm.steady_slip(p, w, robot)
        sc = make_scenario("straight", cid, speed_mps=1.0, duration_s=30.0, brake=False)
        res = Simulator(sc, seed=cid, params=[p]).run()
        s_nom = float(np.mean(res.mean_true_slip(15.0, 30.0)))
        peak = float(res.true_slip()[res.t_s < 3.0].max())
        sim_means.append(s_nom)
        energy[name] = res.energy_j / res.distance_m
        real = [float(np.mean(Simulator(sc, seed=100 + k).run().mean_true_slip(15.0, 30.0))) for k in range(n_real)]
        ok = "yes" if lo <= s_nom <= hi else "**NO**"
        rows.append([cid, name, f"{lo:g} .. {hi:g}", f"{root:.4f}", f"{s_nom:.4f}", ok,
                     f"{np.mean(real):.3f} ± {np.std(real):.3f}", f"{peak:.2f}", f"{energy[name]:.0f}"])
    lines.append(_table(["id", "class", "target", "root mu_net=0", "sim nominal", "in range",
                         "sim realisations", "peak (start)", "energy J/m"], rows))
    mono = all(b >= a - 0.02 for a, b in zip(sim_means, sim_means[1:]))
    lines += ["", f"Non-decreasing with class id (±0.02): **{'yes' if mono else 'NO'}**. "
              "Energy per metre rises with softness from pavement to dry sand; wet mud (Wong's clayey soil, "
              "7 mm static sinkage under this light robot) costs less per metre than sand: its difficulty is "
              "low net traction (mu_net peak 0.15) and high slip, not compaction.", ""]

    # calibrated parameters
    prow = []
    for p in tm.all_nominal_params():
        if p.model == "burckhardt":
            prow.append([p.name, "Burckhardt", "-", "-", "-", "-", f"C_rr {p.crr}"])
            continue
        pk, mu = _peak(p, w, robot)
        prow.append([p.name, "Bekker+hump" if p.is_bekker else "layer+hump", f"{p.shear_modulus_m:.4f}",
                     f"{p.free_slip:.4f}", f"{p.residual_ratio:g}", f"{p.slip_sinkage:g}",
                     f"peak s {pk:.3f}, mu_net {mu:.3f}"])
    lines += ["### Calibrated terramechanics parameters", "",
              _table(["class", "model", "K (m)", "free slip s_f", "K_r", "slip-sinkage a", "traction peak"], prow), ""]
    if not quick:
        crow = []
        for name in CALIBRATION_TARGETS:
            p = calibrate_class(name, robot)
            rec = tm.nominal_params(name)
            crow.append([name, f"{p.shear_modulus_m:.4f} (recorded {rec.shear_modulus_m:.4f})",
                         f"{p.free_slip:.4f} (recorded {rec.free_slip:.4f})",
                         f"{tm.steady_slip(p, w, robot):.4f}"])
        lines += ["Re-derived by `calibrate_class` (least squares, targets in `CALIBRATION_TARGETS`):", "",
                  _table(["class", "K (m)", "s_f", "root"], crow), ""]

    # physics sanity
    res = Simulator(make_scenario("straight", 0, duration_s=30.0, brake=False), seed=0, spread=0.0).run()
    rows100 = np.flatnonzero((res.t_s >= 15.0) & (np.arange(len(res.t_s)) % 2 == 0))
    meas = sample_dict(res, res.log, rows100, robot)
    i_mean = np.mean([np.mean(meas[f"wheel{i}_current_a"]) for i in (1, 2, 3)])
    i_exp = 0.012 * w * robot.wheel_radius_m / robot.torque_constant_nm_per_a
    brake = {}
    for name in ("pavement", "short_grass", "gravel_on_firm_soil"):
        sc = make_scenario("straight", name, duration_s=8.0, brake=True, brake_decel_mps2=2.5)
        r = Simulator(sc, seed=3, spread=0.0).run()
        m = (r.t_s > 5.55) & (r.t_s < 5.8)
        brake[name] = float(np.mean(r.true_slip()[m]))
    lines += ["### Physics sanity", "",
              _table(["check", "value", "expected"], [
                  ["pavement, 1 m/s: mean wheel current", f"{i_mean:.3f} A", f"C_rr W R / k_t = {i_exp:.3f} A (±20%)"],
                  *[[f"hard brake (2.5 m/s^2), {k}: mean true slip", f"{v:+.3f}", "< 0"] for k, v in brake.items()],
              ]), ""]

    # sensors
    from scipy.signal import butter, correlate, filtfilt

    res = simulate("short_grass", "stop_and_go", speed_mps=1.0, duration_s=30.0, seed=5)
    rows = np.arange(0, len(res.log), 2)
    meas = sample_dict(res, res.log, rows, robot)
    bb, aa = butter(2, 2.0, fs=100.0)
    lags = []
    for i in range(3):
        a = np.diff(filtfilt(bb, aa, meas[f"wheel{i + 1}_omega_radps"]))
        b = np.diff(filtfilt(bb, aa, res.wblock("omega")[rows, i]))
        xc = correlate(a - a.mean(), b - b.mean(), mode="full")
        lg = np.arange(-len(b) + 1, len(a))
        k = int(np.argmax(xc))
        y0, y1, y2 = xc[k - 1], xc[k], xc[k + 1]
        lags.append((lg[k] + 0.5 * (y0 - y2) / (y0 - 2 * y1 + y2)) * 10.0)
    lines += ["### Sensors", "",
              f"Encoder lag behind true wheel speed (cross-correlation of 2 Hz zero-phase-filtered speed changes, "
              f"3 wheels, stop-and-go on grass): {', '.join(f'{v:.1f}' for v in lags)} ms (target 30-60 ms). "
              "Camera lever arm, ingest recovery and determinism are checked in `tests/sim/test_simulator.py`.",
              "", f"_sim_calibration took {time.perf_counter() - t0:.0f} s._", ""]
    return "\n".join(lines)


if __name__ == "__main__":  # pragma: no cover
    import sys

    print(run(quick="--quick" in sys.argv))
