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
    from terrainml.stream.app.options import ServeOptions
    from terrainml.stream.app.runner import run_predict

    n_ticks = len(load_run(sim_log, robot=load_robot()).table)
    out = tmp_path / "served.mcap"
    code = run_predict(ServeOptions(model=model_dir, source=str(sim_log), sinks=(f"mcap:{out}", "stdout",)))
    assert code == 0
    stdout = capsys.readouterr().out.splitlines()
    assert len(stdout) == n_ticks
    with open(out, "rb") as fh:
        msgs = [json.loads(m.data) for _, _, m in make_reader(fh).iter_messages()]
    assert [m["seq"] for m in msgs] == list(range(n_ticks))
    assert [json.loads(x)["t_s"] for x in stdout] == [m["t_s"] for m in msgs]
    assert msgs[0]["fallback"] and msgs[0]["fallback_reason"] == "no_classification"


def test_realtime_paces_a_log_at_its_time_stamps(sim_log):
    from terrainml.stream.transports.sources import SourceOptions, open_source

    n = 0
    for s in open_source(str(sim_log), SourceOptions(realtime=True), robot=load_robot()):
        if n == 0:
            t0 = time.perf_counter()  # the clock starts with the first sample (after ingest)
        n += 1
        if s.t_s >= 1.0:
            break
    elapsed = time.perf_counter() - t0
    assert n >= 100
    assert 0.9 <= elapsed < 3.0  # 1 s of log takes 1 s of wall clock


def test_replay_summary_segments_cover_every_tick(sim_log, model_dir):
    from terrainml.io.ingest import load_run
    from terrainml.stream.app.scoring import replay_summary

    segs = replay_summary(model_dir, sim_log)
    assert sum(s["ticks"] for s in segs) == len(load_run(sim_log, robot=load_robot()).table)
    assert segs[0]["fallback_reason"] == "no_classification" and segs[0]["true_class"] == 0


# ------------------------------------------------------------ another robot's logs: --topics, --format
R_HUSKY = 0.1651  # m, the Husky spec's wheel radius (terrainml/robots/husky.yaml)

CSV_SPEC = {  # a single-file CSV layout: ms stamps, m/s side speeds, mA side currents
    "name": "side_csv", "robot": "husky", "run_id": "{run}",
    "sides": {"left": [1, 3], "right": [2, 4]},
    "label": {"from": "none"},
    "files": {"w": {"pattern": "drive_{run}.csv", "time": {"column": "stamp_ms", "unit": "ms"},
                    "columns": {"v_left": {"to": "wheel{i}_omega_radps", "wheels": "left", "unit": "m/s"},
                                "v_right": {"to": "wheel{i}_omega_radps", "wheels": "right", "unit": "m/s"},
                                "i_left": {"to": "wheel{i}_current_a", "wheels": "left", "unit": "mA"},
                                "i_right": {"to": "wheel{i}_current_a", "wheels": "right", "unit": "mA"}}}},
}


def _side_csv(tmp_path):
    import numpy as np
    import pandas as pd
    import yaml

    t_ms = np.arange(0, 2000, 10)  # 2 s at 100 Hz, constant values: resampling changes nothing
    pd.DataFrame({"stamp_ms": t_ms, "v_left": 0.33, "v_right": 0.66, "i_left": 1500.0,
                  "i_right": 2500.0}).to_csv(tmp_path / "drive_01.csv", index=False)
    spec = tmp_path / "spec.yaml"
    spec.write_text(yaml.safe_dump(CSV_SPEC, sort_keys=False))
    return tmp_path / "drive_01.csv", spec


def test_csv_source_with_a_dataset_spec_gets_si_units_and_sides(tmp_path):
    """--format SPEC: m/s side speeds become rad/s = v / R on both wheels of a side, mA become A."""
    from terrainml.stream.transports.sources import SourceOptions, open_source

    csv, spec = _side_csv(tmp_path)
    samples = list(open_source(str(csv), SourceOptions(dataset=str(spec)), robot=load_robot("husky")))
    assert len(samples) == 200
    s = samples[50].columns
    assert samples[50].t_s == s["t_s"] == pytest.approx(0.5)                       # 500 ms
    for i, v in ((1, 0.33), (3, 0.33), (2, 0.66), (4, 0.66)):   # left -> 1, 3; right -> 2, 4
        assert s[f"wheel{i}_omega_radps"] == pytest.approx(v / R_HUSKY)  # 0.33 / 0.1651 = 1.9988 rad/s
    assert s["wheel1_current_a"] == pytest.approx(1.5) and s["wheel4_current_a"] == pytest.approx(2.5)
    # without the spec the file's columns mean nothing to the canonical table: refused, named
    from terrainml.stream.transports.sources import SourceError

    with pytest.raises(SourceError, match="drive_01.csv"):
        next(iter(open_source(str(csv), robot=load_robot("husky"))))


def test_topic_map_reads_a_log_with_other_topic_names(tmp_path):
    """--topics MAP: a log whose topics are named differently is read through the map."""
    import yaml

    from terrainml.io import topics
    from terrainml.io.mcap_writer import RosMcapWriter
    from terrainml.io.topicmap import load_topic_map
    from terrainml.stream.transports.sources import SourceError, SourceOptions, open_source

    names = {topics.IMU: "/robot/imu", topics.WHEEL_JOINTS: "/robot/joints",
             topics.MOTOR_CURRENT: "/robot/currents"}
    log = tmp_path / "other.mcap"
    with RosMcapWriter(log, 3, topic_names=names) as w:
        for k in range(200):
            t = k / 100.0
            w.write_imu(t, (0.0, 0.0, 9.81), (0.0, 0.0, 0.2))
            w.write_wheel_joints(t, [i + t for i in range(1, 4)], [0.0, 0.0, 0.0])
            w.write_motor_current(t, [2.0 + i for i in range(1, 4)])
    doc = load_topic_map("default").to_dict()
    for src in doc["sources"]:
        src["topic"] = names.get(src["topic"], src["topic"])
    tmap = tmp_path / "map.yaml"
    tmap.write_text(yaml.safe_dump(doc, sort_keys=False))
    with pytest.raises(SourceError):  # the default map finds none of the required topics
        next(iter(open_source(str(log), robot=load_robot())))
    samples = list(open_source(str(log), SourceOptions(topic_map=str(tmap)), robot=load_robot()))
    s = samples[100].columns
    assert samples[100].t_s == s["t_s"] == pytest.approx(1.0)
    assert [s[f"wheel{i}_omega_radps"] for i in (1, 2, 3)] == pytest.approx([2.0, 3.0, 4.0])  # i + t
    assert [s[f"wheel{i}_current_a"] for i in (1, 2, 3)] == pytest.approx([3.0, 4.0, 5.0])    # 2 + i
    assert s["imu_yaw_rate_radps"] == pytest.approx(0.2)


def test_topics_and_format_are_refused_for_udp_and_stdin():
    from terrainml.stream.transports.sources import SourceError, SourceOptions, open_source

    for src in ("-", "udp://127.0.0.1:0"):
        with pytest.raises(SourceError, match="apply to a log file"):
            open_source(src, SourceOptions(topic_map="default"))


def test_predict_on_a_full_disk_counts_every_lost_tick_of_the_mcap_sink(sim_log, model_dir, tmp_path,
                                                                         monkeypatch, capsys):
    """The recording's disk is full (ENOSPC from its file object): serving goes
    on (exit 0, every tick on stdout), the summary counts each lost tick, not one error, and no
    recording is left at the sink's path as if complete."""
    import terrainml.stream.transports.sinks as sinks
    from terrainml.io.ingest import load_run
    from terrainml.stream.app.options import ServeOptions
    from terrainml.stream.app.runner import run_predict

    from disk_full import full_disk_open

    n_ticks = len(load_run(sim_log, robot=load_robot()).table)
    out = tmp_path / "served.mcap"
    monkeypatch.setattr(sinks, "open", full_disk_open(2_000), raising=False)
    code = run_predict(ServeOptions(model=model_dir, source=str(sim_log), sinks=(f"mcap:{out}", "stdout",)))
    assert code == 0
    captured = capsys.readouterr()
    assert len(captured.out.splitlines()) == n_ticks
    assert f"sink errors: {{'mcap:{out}': {n_ticks}}}" in captured.err.replace("\n", "")
    assert not out.exists() and "Traceback" not in captured.err


def test_a_log_source_yields_typed_samples_and_counts_a_row_without_a_time(sim_log):
    """Every row is checked once, where the source makes it: a typed Sample; a row whose t_s is not
    finite is counted as malformed and skipped, the stream goes on."""
    import math

    from terrainml.io.ingest import load_run
    from terrainml.stream.tick.sample import Sample
    from terrainml.stream.transports.sources import MALFORMED_REASONS, SourceCounters, iter_table_samples

    table = load_run(sim_log, robot=load_robot()).table.head(50).copy()
    table["t_s"] = table["t_s"].astype(float)
    table.loc[10, "t_s"] = math.nan
    table.loc[20, "t_s"] = math.inf
    counters = SourceCounters()
    samples = list(iter_table_samples(table, counters=counters))
    assert len(samples) == 48 and all(type(s) is Sample for s in samples)
    assert [s.t_s for s in samples] == [s.columns["t_s"] for s in samples]
    assert counters.malformed == 2 and counters.malformed_by_reason == {"t_s_not_finite": 2}
    assert set(counters.malformed_by_reason) <= set(MALFORMED_REASONS)
