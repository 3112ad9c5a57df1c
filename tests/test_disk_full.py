"""Disk-full and unwritable outputs: every command that writes refuses with one
``error:`` line naming its output, exit code 2, no traceback, and leaves nothing at the output path.

Two ways of filling the disk, both on real paths in ``tmp_path``: ``RLIMIT_FSIZE`` (the kernel
refuses any write past N bytes of a file with ``EFBIG``, the file-size limit; SIGXFSZ ignored) for
the commands whose writers are C++ (Arrow) or many files, and an injected ``OSError(ENOSPC)`` in
the file object of the MCAP writers. Ground truth is the file system after the command: the final
path does not exist, and no ``.NAME.part`` is left either.
"""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

import terrainml.io.mcap_writer as mcap_writer
from terrainml.cli import app
from terrainml.stream.tick.message import DesiredSlip
from terrainml.stream.transports.sinks import GuardedSink, McapSink

from cli_refusal import assert_refused
from disk_full import file_size_limit, full_disk_open

runner = CliRunner()


def _nothing_left(out):
    assert not out.exists(), out
    assert not out.with_name(f".{out.name}.part").exists()


def _refused_full(args, out):
    res = runner.invoke(app, args)
    assert_refused(res, out)
    assert "Traceback" not in (res.stderr if res.stderr_bytes is not None else "")
    _nothing_left(out)
    return res


# ----------------------------------------------------------------------------- sim generate
def test_sim_generate_on_a_full_disk_names_the_log_and_leaves_nothing(tmp_path, monkeypatch):
    out = tmp_path / "grass.mcap"
    monkeypatch.setattr(mcap_writer, "open", full_disk_open(200_000), raising=False)
    res = _refused_full(["sim", "generate", "--terrain", "short_grass", "--duration-s", "5", "--out", str(out)], out)
    assert "No space left" in res.output


def test_sim_generate_parquet_at_the_file_size_limit(tmp_path):
    out = tmp_path / "grass.parquet"
    with file_size_limit(50_000):
        _refused_full(["sim", "generate", "--terrain", "short_grass", "--duration-s", "5", "--out", str(out)], out)


def test_sim_generate_dataset_on_a_full_disk_writes_no_index(tmp_path, monkeypatch):
    out = tmp_path / "simdata"
    monkeypatch.setattr(mcap_writer, "open", full_disk_open(100_000), raising=False)
    res = runner.invoke(app, ["sim", "generate", "--runs-per-class", "1", "--duration-s", "5", "--out", str(out)])
    assert_refused(res, ".mcap")
    assert not (out / "index.csv").exists() and not list(out.rglob(".*.part"))


# ----------------------------------------------------------------------------- ingest
@pytest.fixture
def sim_log(tmp_path):
    log = tmp_path / "in" / "grass.mcap"
    res = runner.invoke(app, ["sim", "generate", "--terrain", "short_grass", "--duration-s", "6", "--out", str(log)])
    assert res.exit_code == 0, res.output
    return log


def test_ingest_on_a_full_disk_names_the_output_not_the_log(tmp_path, sim_log):
    out = tmp_path / "run.parquet"
    with file_size_limit(20_000):
        res = _refused_full(["ingest", str(sim_log), "--out", str(out), "--chunk-s", "0.5"], out)
    assert f"{sim_log}:" not in res.output.replace("\n", "")   # the input is not blamed


# ----------------------------------------------------------------------------- dataset build, train
@pytest.fixture
def sim_runs(tmp_path):
    out = tmp_path / "simdata"
    res = runner.invoke(app, ["sim", "generate", "--runs-per-class", "1", "--duration-s", "20", "--format",
                              "parquet", "--out", str(out)])
    assert res.exit_code == 0, res.output
    return out


def test_dataset_build_on_a_full_disk(tmp_path, sim_runs):
    out = tmp_path / "windows.parquet"
    with file_size_limit(10_000):
        _refused_full(["dataset", "build", str(sim_runs), "--out", str(out), "--quiet"], out)


def test_a_model_manifest_is_written_whole_or_not_at_all(tmp_path):
    from terrainml.atomic import OutputWriteError, write_text

    out = tmp_path / "model" / "manifest.json"
    with file_size_limit(1_000), pytest.raises(OutputWriteError, match=str(out)):
        write_text(out, "x" * 5_000)     # the manifest of a model folder (train) is written so
    _nothing_left(out)


# ----------------------------------------------------------------------------- estimate
def test_estimate_on_a_full_disk(tmp_path, sim_runs):
    run = sorted(sim_runs.glob("*.parquet"))[0]
    out = tmp_path / "est.parquet"
    with file_size_limit(10_000):
        _refused_full(["estimate", str(run), "--out", str(out)], out)


# ----------------------------------------------------------------------------- predict's MCAP sink
def _msg(k: int) -> DesiredSlip:
    return DesiredSlip(t_s=k * 0.01, seq=k, slip_desired=[0.1] * 3, slip_measured=[0.1] * 3,
                       wheel_state=["steady"] * 3, terrain_class=1, terrain_name="short_grass", confidence=0.9,
                       class_probabilities=[0.9, 0.1], classification_age_s=0.0, fallback=False,
                       fallback_reason="", estimator_ok=True)


def test_mcap_sink_counts_every_lost_tick_and_leaves_no_recording(tmp_path, monkeypatch):
    import terrainml.stream.transports.sinks as sinks

    out = tmp_path / "slip.mcap"
    monkeypatch.setattr(sinks, "open", full_disk_open(100_000), raising=False)
    g = GuardedSink(McapSink(out))
    n = 20_000
    for k in range(n):
        g.send(_msg(k))
    g.close()
    # lost ticks counted, not one error: every tick is either sent or lost, most are lost
    assert g.sent + g.errors == n and g.errors > n // 2 and g.sent > 0
    assert not out.exists()    # the cut recording is only ever the hidden .slip.mcap.part


def test_mcap_sink_complete_recording_appears_only_on_close(tmp_path):
    out = tmp_path / "slip.mcap"
    s = McapSink(out)
    s.send(_msg(0))
    assert not out.exists()
    s.close()
    assert out.exists() and not out.with_name(".slip.mcap.part").exists()


# ----------------------------------------------------------------------------- lookup build (the table export)
def test_lookup_build_on_a_full_disk(tmp_path):
    out = tmp_path / "table.json"
    with file_size_limit(1_000):
        _refused_full(["lookup", "build", "--out", str(out)], out)
