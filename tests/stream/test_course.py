"""Acceptance: a simulated mixed-terrain course served by the predictor.

A model trained on simulated straight runs of four classes serves a course that crosses all
four with transitions. Truth is the simulator's class under the robot.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from terrainml.robot import load_robot

COURSE = [0, 5, 2, 7, 3]  # >= 4 classes, 4 transitions
TRAIN_CLASSES = sorted(set(COURSE))
SETTLE_S = 2.5


@pytest.fixture(scope="module")
def sim_model_dir(tmp_path_factory):
    from terrainml.estimation.run import estimate_run
    from terrainml.features.sets import FeatureSet
    from terrainml.features.windows import Windows, WindowSpec, cut_windows
    from terrainml.lookup.table import DesiredSlipTable
    from terrainml.models.artifacts import TrainingProvenance, save_artifact
    from terrainml.models.svm import SVMClassifier
    from terrainml.sim.generate import simulate
    from terrainml.sim.output import run_table
    from terrainml.classes import TERRAIN_CLASSES

    robot = load_robot()
    wins = []
    for c in TRAIN_CLASSES:
        for rep in range(2):
            res = simulate(c, "straight", duration_s=30.0, seed=1000 + 10 * c + rep,
                           speed_mps=[0.9, 1.1][rep])
            est = estimate_run(run_table(res, f"c{c}r{rep}"), robot)
            w, _ = cut_windows(est, robot)
            wins.append(w)
    wins = Windows.concat(wins)
    missing = sorted(set(TRAIN_CLASSES) - set(wins.y.tolist()))
    assert not missing, f"no steady training windows for classes {missing} from straight runs"
    clf = SVMClassifier(FeatureSet.for_robot(robot), C_grid=[1.0, 10.0], gamma_grid=["scale"],
                        inner_folds=2).fit(wins, wins.y)
    out = tmp_path_factory.mktemp("simmodel") / "course_svm"
    save_artifact(out, {"svm": clf}, TrainingProvenance(
                      classes=TRAIN_CLASSES, class_names=[TERRAIN_CLASSES[c] for c in TRAIN_CLASSES],
                      channels=list(wins.channels), window_spec=WindowSpec(), robot=robot,
                      training_fingerprint="test-course"),
                  attachments={"desired_slip_table.json": DesiredSlipTable.build(robot).to_json()})
    return out


@pytest.mark.acceptance
def test_mixed_terrain_course_served_class_matches_truth(sim_model_dir):
    from terrainml.sim.generate import simulate
    from terrainml.sim.output import run_table
    from terrainml.stream.tick.config import ServingConfig
    from terrainml.stream.tick.predictor import Predictor
    from terrainml.stream.transports.sources import iter_table_samples

    res = simulate(None, "mixed", duration_s=110.0, seed=77, terrains=COURSE, speed_mps=1.0)
    table = run_table(res, "course")
    truth = table["terrain"].to_numpy()
    gt_speed = np.hypot(table["gt_vx_mps"], table["gt_vy_mps"]).to_numpy()
    served_input = table.drop(columns=[c for c in table.columns
                                       if c.startswith("gt_") or c in ("terrain", "run_id")])
    pred = Predictor.from_model_dir(sim_model_dir, config=ServingConfig(classify_lag_ticks=10))
    out = [pred.step(s) for s in iter_table_samples(served_input)]
    pred.close()
    assert len(out) == len(table)
    served = np.array([m.terrain_class for m in out])
    t = table["t_s"].to_numpy()
    # never NaN (the JSON layer would refuse it; check the values themselves too)
    for m in out:
        m.to_json()
        assert all(math.isfinite(v) for v in m.slip_desired + m.slip_measured + m.class_probabilities)
    # fallback flagged at start-up until the first steady window is classified
    first = next(k for k, m in enumerate(out) if not m.fallback)
    assert first >= 199  # a 2 s window needs 200 ticks
    assert all(m.fallback and m.terrain_name == "none"
               and m.fallback_reason in ("no_classification", "estimator_unhealthy",
                                         "uncertain_classification")
               for m in out[:first])
    # steady ticks: moving >= 0.2 m/s at a near-constant true speed (|dv/dt| < 0.15 m/s^2 over
    # 0.5 s), excluding 2.5 s after each transition
    trans_t = t[1:][np.diff(truth) != 0]
    assert len(trans_t) == len(COURSE) - 1
    settled = np.ones(len(t), dtype=bool)
    for tt in trans_t:
        settled &= ~((t >= tt) & (t < tt + SETTLE_S))
    k = 25
    dv = np.zeros(len(t))
    dv[k:-k] = (gt_speed[2 * k:] - gt_speed[:-2 * k]) / (t[2 * k:] - t[:-2 * k])
    steady = (gt_speed >= 0.2) & (np.abs(dv) < 0.15) & settled
    steady[:first] = False  # before the first classification nothing can be served but fallback
    assert steady.sum() > 3000
    acc = float((served[steady] == truth[steady]).mean())
    print(f"course: served class == truth on {acc:.3f} of {steady.sum()} steady ticks")
    assert acc >= 0.90
