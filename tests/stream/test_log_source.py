"""A recorded MCAP log as the source (ingest + resampling of the io owner), MCAP as the sink."""

from __future__ import annotations

import json
import time

import pytest

from terrainml.robot import load_robot


@pytest.fixture(scope="module")
def sim_log(tmp_path_factory):
    from terrainml.sim.generate import simulate
    from terrainml.sim.output import write_mcap

    res = simulate(0, "straight", duration_s=8.0, seed=5)
    return write_mcap(res, tmp_path_factory.mktemp("log") / "pavement.mcap", "pavement")


def test_mcap_log_replayed_tick_by_tick_into_an_mcap_recording(sim_log, model_dir, tmp_path, capsys):
    from mcap.reader import make_reader

    from terrainml.io.ingest import load_run
    from terrainml.stream.runner import run_predict

    n_ticks = len(load_run(sim_log, robot=load_robot()).table)
    out = tmp_path / "served.mcap"
    code = run_predict(model=model_dir, source=str(sim_log), sinks=[f"mcap:{out}", "stdout"])
    assert code == 0
    stdout = capsys.readouterr().out.splitlines()
    assert len(stdout) == n_ticks
    with open(out, "rb") as fh:
        msgs = [json.loads(m.data) for _, _, m in make_reader(fh).iter_messages()]
    assert [m["seq"] for m in msgs] == list(range(n_ticks))
    assert [json.loads(x)["t_s"] for x in stdout] == [m["t_s"] for m in msgs]
    assert msgs[0]["fallback"] and msgs[0]["fallback_reason"] == "no_classification"


def test_realtime_paces_a_log_at_its_time_stamps(sim_log):
    from terrainml.stream.sources import open_source

    n = 0
    for s in open_source(str(sim_log), robot=load_robot(), realtime=True):
        if n == 0:
            t0 = time.perf_counter()  # the clock starts with the first sample (after ingest)
        n += 1
        if s["t_s"] >= 1.0:
            break
    elapsed = time.perf_counter() - t0
    assert n >= 100
    assert 0.9 <= elapsed < 3.0  # 1 s of log takes 1 s of wall clock


def test_replay_summary_segments_cover_every_tick(sim_log, model_dir):
    from terrainml.io.ingest import load_run
    from terrainml.stream.runner import replay_summary

    segs = replay_summary(model_dir, sim_log)
    assert sum(s["ticks"] for s in segs) == len(load_run(sim_log, robot=load_robot()).table)
    assert segs[0]["fallback_reason"] == "no_classification" and segs[0]["true_class"] == 0
