"""EKF model: analytic Jacobians vs finite differences, the compiled filter vs the numpy
reference (``terrainml.estimation.reference``) and filterpy, covariance health, invalid rows."""

import math

import numpy as np
import pytest

from terrainml.estimation import reference as ref
from terrainml.estimation.ekf import Ekf, PlanarModel, wrap_angle
from terrainml.estimation.online import OnlineEstimator
from terrainml.estimation.reference import ReferenceEkf
from terrainml.estimation.run import estimate_run, estimate_run_detailed
from terrainml.robot import load_robot
from terrainml.testing import kinematic_run


def _fd_jacobian(fun, x, eps=1e-6):
    cols = []
    for j in range(len(x)):
        e = np.zeros_like(x)
        e[j] = eps
        cols.append((fun(x + e) - fun(x - e)) / (2 * eps))
    return np.column_stack(cols)


@pytest.mark.parametrize("robot_name", ["agrimaro", "husky"])
def test_jacobians_match_finite_differences(robot_name):
    model = PlanarModel(load_robot(robot_name))
    rng = np.random.default_rng(7)
    for _ in range(20):
        x = rng.normal(0, 1, model.n)
        x[2] = rng.uniform(-3, 3)
        dt = 0.01 + 0.1 * rng.random()
        F_fd = _fd_jacobian(lambda xx: model.f(xx, dt), x)
        H_fd = _fd_jacobian(model.h, x)
        np.testing.assert_allclose(model.F(x, dt), F_fd, rtol=1e-6, atol=1e-8)
        np.testing.assert_allclose(model.H(x), H_fd, rtol=1e-6, atol=1e-8)
        # the kernels' model (written once, in _kernel) against the reference's own equations
        np.testing.assert_allclose(model.f(x, dt), ref.f(model, x, dt), rtol=0, atol=1e-12)
        np.testing.assert_allclose(model.F(x, dt), ref.F(model, x, dt), rtol=0, atol=1e-12)
        np.testing.assert_allclose(model.h(x), ref.h(model, x), rtol=0, atol=1e-12)
        np.testing.assert_allclose(model.H(x), ref.H(model, x), rtol=0, atol=1e-12)


def test_model_shapes_follow_robot():
    a = PlanarModel(load_robot("agrimaro"))
    h = PlanarModel(load_robot("husky"))
    assert a.n == 12 and a.m == 14  # thesis: 12 states, 14 measurements (eq. 6.1, 6.3)
    assert h.n == 9  # no steering states
    assert not any(r.group in ("cam", "steer") for r in h.rows)  # no camera, no steering rows
    assert [r.name for r in h.rows][:4] == ["wheel1_omega", "wheel2_omega", "wheel3_omega", "wheel4_omega"]


def test_wrap_angle():
    assert wrap_angle(math.pi) == pytest.approx(math.pi)
    assert wrap_angle(-math.pi) == pytest.approx(math.pi)
    assert wrap_angle(3 * math.pi / 2) == pytest.approx(-math.pi / 2)


def test_angle_innovation_is_wrapped():
    model = PlanarModel(load_robot("agrimaro"))
    ekf = Ekf(model, "thesis")
    ekf.x[2] = math.pi - 0.01
    z = np.zeros(model.m)
    use = np.zeros(model.m, dtype=bool)
    k = [r.name for r in model.rows].index("cam_yaw")
    z[k] = -math.pi + 0.01  # 0.02 rad away across the wrap, not 2 pi - 0.02
    use[k] = True
    ekf.update(z, use, np.full(model.m, 5e-4))
    assert abs(ekf.y[k] - 0.02) < 1e-12
    assert abs(wrap_angle(ekf.x[2] - (math.pi - 0.01))) < 0.02


def test_covariance_stays_spd_over_ten_minutes():
    # 10 min at 100 Hz of mixed driving (arcs, omni, reversal), camera dropouts
    def vx(t):
        return 0.8 * np.sin(2 * np.pi * t / 60.0)

    def vy(t):
        return 0.3 * np.sin(2 * np.pi * t / 37.0)

    def r(t):
        return 0.3 * np.sin(2 * np.pi * t / 23.0)

    df = kinematic_run(duration_s=600.0, vx=vx, vy=vy, yaw_rate=r, slip=0.1, seed=3,
                       cam_dropouts=((100.0, 103.0), (400.0, 400.5)))
    bad = []

    def check(k, est):
        if k % 250 == 0:
            P = est.ekf.P
            if not np.array_equal(P, P.T) or np.linalg.eigvalsh(P).min() <= 0:
                bad.append(k)

    for preset in ("thesis", "robust"):
        est, _ = estimate_run_detailed(df, preset=preset, on_tick=check)
        assert not bad, f"{preset}: P not SPD at ticks {bad[:5]}"
        assert np.isfinite(est[["ekf_vx_mps", "ekf_vy_mps", "ekf_yaw_rate_radps"]].to_numpy()).all()


def test_invalid_rows_are_dropped_not_fed():
    base = kinematic_run(duration_s=8.0, slip=0.2, seed=5, cam_dropouts=((3.0, 4.0),))
    garbage = base.copy()
    drop = (garbage.t_s >= 3.0) & (garbage.t_s < 4.0)
    # same ticks flagged invalid, but holding absurd values instead of NaN
    for c in ("cam_vx_mps", "cam_vy_mps", "cam_yaw_rate_radps", "cam_yaw_rad"):
        garbage.loc[drop, c] = 1e6
    imu_bad = (garbage.t_s >= 5.0) & (garbage.t_s < 5.5)
    garbage.loc[imu_bad, "imu_ax_mps2"] = 1e6
    garbage.loc[imu_bad, "imu_valid"] = False
    base2 = base.copy()
    base2.loc[imu_bad, ["imu_ax_mps2", "imu_ay_mps2", "imu_yaw_rate_radps", "imu_yaw_rad"]] = np.nan
    a = estimate_run(base2)
    b = estimate_run(garbage)
    np.testing.assert_array_equal(a["ekf_vx_mps"].to_numpy(), b["ekf_vx_mps"].to_numpy())
    # during the camera gap the rows are absent: fewer dof
    assert (a.loc[drop, "nis_dof"] < a.loc[~drop & (a.t_s > 1), "nis_dof"].max()).all()


def test_online_estimator_with_compiled_filter_equals_numpy_reference():
    df = kinematic_run(duration_s=12.0, slip=0.2, seed=8, yaw_rate=lambda t: 0.3 * np.sin(0.5 * t),
                       cam_dropouts=((5.0, 5.6),))
    df.loc[300:302, "cam_vx_mps"] += 0.8  # a camera glitch for the gate
    for preset in ("thesis", "robust"):
        outs = []
        for filt in (ReferenceEkf, Ekf):
            est = OnlineEstimator(load_robot("agrimaro"), preset)
            est.ekf = filt(est.model, preset)
            xs = []
            for rec in df.to_dict("records"):
                est.step(rec)
                xs.append(np.concatenate([est.ekf.x, est.ekf.P.ravel(), [est.ekf.nis]]))
            outs.append((np.array(xs), est.ekf.n_gated))
        np.testing.assert_allclose(outs[1][0], outs[0][0], rtol=1e-9, atol=1e-9, err_msg=preset)
        assert outs[0][1] == outs[1][1]


def _bare_sequence(preset):
    """Measurements of a run as the bare EKF sees them: a camera glitch (for the gate) and a
    camera dropout (rows absent)."""
    from terrainml.estimation.online import OnlineEstimator

    df = kinematic_run(duration_s=8.0, slip=0.2, seed=4, yaw_rate=lambda t: 0.3 * np.sin(0.5 * t),
                       cam_dropouts=((3.0, 3.5),))
    df.loc[200:202, "cam_vx_mps"] += 0.8
    est = OnlineEstimator(load_robot("agrimaro"), preset)
    Z = np.column_stack([df[c].to_numpy(float) for c in est.row_columns])
    return est.model, df["t_s"].to_numpy(), Z, np.isfinite(Z), est._r_base


@pytest.mark.parametrize("preset", ["thesis", "robust"])
def test_whole_table_and_tick_by_tick_are_the_same_filter(preset):
    # offline (batch_filter: whole table), online (step: one tick) and predict()+update() are one
    # filter: the same numbers, gate decisions included; the numpy reference agrees to 1e-9
    model, t, Z, use, r = _bare_sequence(preset)
    xs_batch, nis_batch, dof_batch = Ekf(model, preset).batch_filter(t, Z, use, r)
    ekf_step, ekf_pu = Ekf(model, preset), Ekf(model, preset)
    xs_step, xs_pu, nis_step = np.empty_like(xs_batch), np.empty_like(xs_batch), np.empty(len(t))
    for k in range(len(t)):
        ekf_step.step(t[k] - t[k - 1] if k else 0.0, Z[k], use[k], r)
        if k:
            ekf_pu.predict(t[k] - t[k - 1])
        ekf_pu.update(Z[k], use[k], r)
        xs_step[k], xs_pu[k], nis_step[k] = ekf_step.x, ekf_pu.x, ekf_step.nis
    np.testing.assert_array_equal(xs_batch, xs_step)
    np.testing.assert_array_equal(xs_batch, xs_pu)
    np.testing.assert_array_equal(nis_batch, nis_step)
    assert dof_batch.max() == model.m and dof_batch.min() < model.m  # all rows, and the dropout
    reference = ReferenceEkf(model, preset)
    xs_ref, nis_ref, dof_ref = reference.batch_filter(t, Z, use, r)
    np.testing.assert_allclose(xs_batch, xs_ref, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(nis_batch, nis_ref, rtol=1e-9, atol=1e-9)
    np.testing.assert_array_equal(dof_batch, dof_ref)
    if preset == "robust":  # the glitch was gated, identically on every path
        assert reference.n_gated > 0 and ekf_step.n_gated == ekf_pu.n_gated == reference.n_gated


@pytest.mark.parametrize("preset", ["thesis", "robust"])
def test_filter_matches_filterpy(preset):
    # filterpy's ExtendedKalmanFilter (textbook equations) on the same model, f/F/h/H from the
    # reference; no gate (filterpy has none): the same estimates to round-off
    kalman = pytest.importorskip("filterpy.kalman")
    model, t, Z, use, r = _bare_sequence(preset)
    t, Z, use = t[:400], Z[:400], use[:400]
    ours = Ekf(model, preset)
    xs = ours.batch_filter(t, Z, use, r, gate_enabled=False)[0]

    class _Ekf(kalman.ExtendedKalmanFilter):
        def predict_x(self, u=0):
            self.x = ref.f(model, self.x, self.dt)

    kf = _Ekf(dim_x=model.n, dim_z=model.m)
    kf.x, kf.P = np.zeros(model.n), Ekf(model, preset).P
    angle = np.array([row.angle for row in model.rows])
    for k in range(len(t)):
        if k:
            kf.dt = t[k] - t[k - 1]
            kf.F, kf.Q = ref.F(model, kf.x, kf.dt), ours.Q0 * (kf.dt / 0.01)
            kf.predict()
        m = use[k]

        def resid(a, b, ang=angle[m]):
            y = a - b
            y[ang] = np.mod(y[ang] + math.pi, 2 * math.pi) - math.pi
            return y

        kf.update(Z[k][m], lambda x, m=m: ref.H(model, x)[m], lambda x, m=m: ref.h(model, x)[m],
                  R=np.diag(r[m]), residual=resid)
        kf.x[2] = ref.wrap(kf.x[2])
        np.testing.assert_allclose(xs[k], kf.x, rtol=1e-9, atol=1e-9, err_msg=f"tick {k}")


def test_estimate_run_without_numba_matches_compiled():
    # the pure-Python fallback (TERRAINML_NO_NUMBA=1: platforms without numba; the kernels run as
    # plain Python) gives the same EST table as the compiled kernels, to round-off
    import json
    import subprocess
    import sys

    from terrainml.estimation import _kernel

    if not _kernel.HAVE_NUMBA:
        pytest.skip("numba not installed: this process already runs the fallback")
    code = ("import json, numpy as np\n"
            "from terrainml.estimation.run import estimate_run\n"
            "from terrainml.testing import kinematic_run\n"
            "df = kinematic_run(duration_s=4.0, slip=0.2, seed=2, cam_dropouts=((2.0, 2.6),))\n"
            "out = {p: estimate_run(df, preset=p) for p in ('thesis', 'robust')}\n"
            "print(json.dumps({p: {'v': e[['ekf_vx_mps', 'ekf_vy_mps', 'slip1', 'v_long2_mps', 'nis']]"
            ".fillna(-999.0).to_numpy().tolist(), 's': e['state1'].tolist(), "
            "'ok': e['estimator_ok'].tolist()} for p, e in out.items()}))\n")
    env = dict(__import__("os").environ, TERRAINML_NO_NUMBA="1")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    fallback = json.loads(res.stdout.strip().splitlines()[-1])
    df = kinematic_run(duration_s=4.0, slip=0.2, seed=2, cam_dropouts=((2.0, 2.6),))
    for preset in ("thesis", "robust"):
        est = estimate_run(df, preset=preset)
        v = est[["ekf_vx_mps", "ekf_vy_mps", "slip1", "v_long2_mps", "nis"]].fillna(-999.0).to_numpy()
        np.testing.assert_allclose(np.array(fallback[preset]["v"]), v, rtol=1e-9, atol=1e-9, err_msg=preset)
        assert fallback[preset]["s"] == est["state1"].tolist()
        assert fallback[preset]["ok"] == est["estimator_ok"].tolist()
