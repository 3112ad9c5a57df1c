"""Mission metrics on hand-made logs: every expected value below is worked out by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from terrainml.experiments.mission_metrics import MissionLog, longest_stall_s, mission_metrics, summarise


def _log(n=11, dt=0.1, n_wheels=2, **over) -> MissionLog:
    """n ticks at dt; 1 m/s commanded and driven; 100 W from the battery; nothing else."""
    t = np.arange(n) * dt
    kw = dict(t_s=t, x_m=t.copy(), y_m=np.zeros(n), speed_mps=np.ones(n), cmd_speed_mps=np.ones(n),
              slip=np.zeros((n, n_wheels)), sinkage_m=np.full((n, n_wheels), 0.01),
              rut_m=np.full((n, n_wheels), 0.005), p_battery_w=np.full(n, 100.0),
              p_drawbar_w=np.full(n, 50.0), p_slip_w=np.zeros((n, n_wheels)),
              loaded=np.ones(n, bool), t_start_s=0.0, t_done_s=1.0, nominal_time_s=1.0,
              clearance_m=0.1)
    kw.update(over)
    return MissionLog(**kw)


def test_distance_energy_and_efficiency_by_hand():
    m = mission_metrics(_log())
    # 11 ticks of 0.1 s at 1 m/s: 1.1 m; 11 x 0.1 s x 100 W = 110 J -> 100 J/m
    assert m["distance_m"] == pytest.approx(1.1)
    assert m["energy_j"] == pytest.approx(110.0)
    assert m["energy_j_per_m"] == pytest.approx(100.0)
    # 50 W of drawbar power out of 100 W from the battery
    assert m["tractive_efficiency"] == pytest.approx(0.5)
    assert m["time_s"] == pytest.approx(1.0) and m["success"] and m["route_done"]
    assert m["max_sinkage_m"] == pytest.approx(0.01) and m["rut_depth_m"] == pytest.approx(0.005)


def test_regeneration_counted_negative_and_efficiency_over_loaded_ticks_only():
    p = np.full(11, 100.0)
    p[5:] = -20.0                       # 6 ticks regenerating
    dp = np.full(11, 50.0)
    loaded = np.zeros(11, bool)
    loaded[:2] = True                   # only 2 loaded ticks: 2 x 50 / 2 x 100
    m = mission_metrics(_log(p_battery_w=p, p_drawbar_w=dp, loaded=loaded))
    assert m["energy_j"] == pytest.approx(0.1 * (5 * 100 - 6 * 20))     # 38 J
    assert m["energy_noregen_j"] == pytest.approx(0.1 * 5 * 100)        # 50 J
    assert m["tractive_efficiency"] == pytest.approx(0.5)


def test_spin_share_counts_wheel_ticks_while_asked_to_move():
    slip = np.zeros((10, 2))
    slip[:4, 0] = 0.9                   # wheel 1 spins 4 ticks
    slip[:2, 1] = 0.85                  # wheel 2 spins 2 ticks
    slip[8:, :] = 0.95                  # both "spin" while the command is 0: not counted
    cmd = np.ones(10)
    cmd[8:] = 0.0
    m = mission_metrics(_log(n=10, slip=slip, cmd_speed_mps=cmd, speed_mps=np.ones(10),
                             sinkage_m=np.zeros((10, 2)), rut_m=np.zeros((10, 2))))
    # 6 spinning wheel-ticks among 8 ticks x 2 wheels
    assert m["spin_share"] == pytest.approx(6 / 16)


def test_slip_work_per_metre():
    p_slip = np.zeros((11, 2))
    p_slip[:, 0] = 30.0                 # 30 W on wheel 1
    p_slip[:, 1] = -5.0                 # negative (noise) is clipped to 0
    m = mission_metrics(_log(p_slip_w=p_slip))
    assert m["slip_work_j"] == pytest.approx(33.0)          # 11 x 0.1 s x 30 W
    assert m["slip_work_j_per_m"] == pytest.approx(30.0)    # over 1.1 m


def test_longest_stall():
    cmd = np.array([0, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5, 0.02, 0.5, 0.5])
    v = np.array([0, 0.05, 0.0, 0.09, 0.2, 0.0, 0.0, 0.0, 0.0, 0.5])
    # stalled (cmd >= 0.05 and v < 0.1): ticks 1,2,3 | 5,6 | 8 (tick 7's command is below 0.05)
    assert longest_stall_s(v, cmd, 1.0) == pytest.approx(3.0)


def test_success_rules():
    assert mission_metrics(_log())["success"]
    # not done: failed, time is the elapsed time
    m = mission_metrics(_log(t_done_s=None))
    assert not m["success"] and not m["route_done"] and m["time_s"] == pytest.approx(1.0)
    # done, but after more than 2x the nominal time
    assert not mission_metrics(_log(nominal_time_s=0.45))["success"]
    assert mission_metrics(_log(nominal_time_s=0.5))["success"]
    # sinkage at the clearance
    assert not mission_metrics(_log(sinkage_m=np.full((11, 2), 0.1)))["success"]
    # a stall of 6.1 s (61 ticks of 0.1 s at 0 speed) fails; one of 5.0 s (50 ticks) does not
    n = 80
    v = np.ones(n)
    v[10:71] = 0.0
    lg = _log(n=n, speed_mps=v, cmd_speed_mps=np.ones(n), t_done_s=7.9, nominal_time_s=10.0,
              sinkage_m=np.zeros((n, 2)), rut_m=np.zeros((n, 2)), p_battery_w=np.ones(n),
              p_drawbar_w=np.ones(n), p_slip_w=np.zeros((n, 2)), loaded=np.ones(n, bool),
              slip=np.zeros((n, 2)), x_m=np.zeros(n), y_m=np.zeros(n), t_s=np.arange(n) * 0.1)
    assert mission_metrics(lg)["longest_stall_s"] == pytest.approx(6.1)
    assert not mission_metrics(lg)["success"]
    v[10:71] = 1.0
    v[10:60] = 0.0
    assert mission_metrics(lg)["success"]


def test_missing_inputs_give_nan_not_values():
    m = mission_metrics(_log(p_drawbar_w=np.full(11, np.nan), rut_m=np.full((11, 2), np.nan)))
    assert math.isnan(m["tractive_efficiency"]) and math.isnan(m["rut_depth_m"])


def test_decimate_keeps_scalars():
    lg = _log().decimate(5)
    assert len(lg.t_s) == 3 and lg.slip.shape == (3, 2) and lg.t_done_s == 1.0


def test_summary_by_family_and_terrain():
    rows = [dict(family="field", terrain="dry_sand", success=s, route_done=s, time_s=t,
                 energy_j_per_m=e, spin_share=0.0, max_sinkage_m=0.01, demand_ratio=0.5)
            for s, t, e in ((True, 10.0, 100.0), (False, 20.0, None), (True, 30.0, 300.0))]
    s = summarise(rows)
    ft = s["by_family_terrain"]["field/dry_sand"]
    assert ft["n"] == 3 and ft["success_rate"] == pytest.approx(2 / 3)
    assert ft["time_s"]["median"] == pytest.approx(20.0)
    assert ft["energy_j_per_m"]["median"] == pytest.approx(200.0)   # the None is left out
    assert s["overall"]["tractive_efficiency"]["median"] is None
