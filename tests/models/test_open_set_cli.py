"""``terrainml evaluate --open-set`` end to end on tiny labelled logs (``logs_synth``): the
leave-one-class-out table on stdout and in the report, and the class whose slip lies farthest
from the others' (known by construction, ``synthetic_runs.CLASS_SLIP``) is found as the unknown."""

from __future__ import annotations

import json

import pandas as pd
import pytest
from typer.testing import CliRunner

from terrainml.cli import app
from terrainml.pipeline.dataset import read_windows

from logs_synth import write_logs
from synthetic_runs import CLASS_SLIP

COLUMNS = ["unknown class", "windows (moving)", "AUROC", "AUROC moving", "unknown flagged % (moving)",
           "false alarms % (known held-out)", "known bal. acc. %",
           "reach: flagged % at 5 % false alarms (upper bound)"]
JSON_COLUMNS = {"unknown", "n_unknown", "n_unknown_moving", "n_known", "auroc", "auroc_moving", "unknown_flagged",
                "unknown_flagged_all", "false_alarm", "false_alarm_moving", "known_balanced_accuracy",
                "unknown_flagged_reach"}


def _farthest_slip_class() -> int:
    """The class whose slip is farthest from every other class's (by construction)."""
    return max(CLASS_SLIP, key=lambda c: min(abs(CLASS_SLIP[c] - CLASS_SLIP[o]) for o in CLASS_SLIP if o != c))


@pytest.fixture(scope="module")
def windows_file(tmp_path_factory):
    folder = tmp_path_factory.mktemp("open_set")
    logs = write_logs(folder / "logs", runs_per_class=3, seed=3)
    w = folder / "windows.parquet"
    r = CliRunner().invoke(app, ["dataset", "build", str(logs), "--out", str(w), "-q"])
    assert r.exit_code == 0, r.output
    return w


def test_evaluate_open_set_writes_the_table_and_finds_the_far_slip_class(windows_file, tmp_path):
    out = tmp_path / "rep"
    r = CliRunner().invoke(app, ["evaluate", "--open-set", "--data", str(windows_file), "--folds", "3",
                                 "--out", str(out), "-q"])
    assert r.exit_code == 0, r.output
    lines = [ln for ln in r.stdout.splitlines() if ln.startswith("|")]
    assert [c.strip() for c in lines[0].strip("|").split("|")] == COLUMNS
    ds = read_windows(windows_file)
    names = dict(zip(ds.class_ids, ds.class_names))
    far = names[_farthest_slip_class()]
    assert len(lines) == 2 + len(CLASS_SLIP) + 1  # header, rule, one row per class, mean
    assert any(ln.startswith(f"| {far} |") for ln in lines)
    doc = json.loads((out / "open_set.json").read_text())
    assert (out / "open_set.md").read_text().count("| **mean** |") == 1
    rows = {row["unknown"]: row for row in doc["per_class"]}
    assert set(rows) == set(names.values())
    assert JSON_COLUMNS <= set(rows[far])
    # every window scored once: the held-out class's windows are its windows in the file
    y = ds.windows.y
    for c, name in names.items():
        assert rows[name]["n_unknown"] == int((y == c).sum())
        assert rows[name]["n_known"] == int((y != c).sum())
    # slip 0.30 against 0.01 and 0.12: the unknown scores above the known classes' held-out runs
    assert rows[far]["auroc_moving"] > 0.9
    assert rows[far]["unknown_flagged"] > rows[far]["false_alarm"]
    assert doc["model"] == "svm" and doc["settings"]["folds"] == 3
    # every window's score is written: the far class's windows score above the others' when it is unknown
    table = pd.read_parquet(out / "open_set_scores.parquet")
    assert len(table) == len(y) and list(table["label"]) == [names[c] for c in y]
    assert list(table["run"]) == [str(g) for g in ds.windows.groups]
    score = table[f"score_without_{far}"]
    assert score[table["label"] == far].median() > score[table["label"] != far].quantile(0.9)
    assert (out / "open_set_roc.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_evaluate_open_set_refusals_name_the_option(windows_file, tmp_path):
    runner = CliRunner()
    r = runner.invoke(app, ["evaluate", "--data", str(windows_file)])
    assert r.exit_code == 2 and "MODEL_DIR" in r.output
    r = runner.invoke(app, ["evaluate", "--open-set", "--data", str(windows_file), "--model", "cnn",
                            "--out", str(tmp_path / "x")])
    assert r.exit_code == 2 and "cnn" in r.output and "feature space" in r.output
    r = runner.invoke(app, ["evaluate", "--open-set", "--data", str(windows_file), "--folds", "1"])
    assert r.exit_code == 2 and "--folds" in r.output


def test_train_open_set_flag_reaches_the_training(windows_file, tmp_path, monkeypatch):
    from terrainml.pipeline import train as train_mod

    seen = {}

    def fake_train(ds, out, kinds, options, *args, **kw):
        seen["options"] = options
        raise ValueError("stop after the call")

    monkeypatch.setattr(train_mod, "train", fake_train)
    r = CliRunner().invoke(app, ["train", "--data", str(windows_file), "--model", "svm", "--no-members",
                                 "--open-set", "--out", str(tmp_path / "m"), "-q"])
    assert r.exit_code == 2 and "stop after the call" in r.output
    assert seen["options"].open_set is True


def test_train_open_set_flag_reaches_the_selecting_training(windows_file, tmp_path, monkeypatch):
    from terrainml.pipeline import autotrain

    seen = {}

    def fake_train_auto(tables, robot, out, options, *args, **kw):
        seen["options"] = options
        raise ValueError("stop after the call")

    monkeypatch.setattr(autotrain, "train_auto", fake_train_auto)
    r = CliRunner().invoke(app, ["train", "--data", str(windows_file), "--open-set", "--out", str(tmp_path / "m"),
                                 "-q"])
    assert r.exit_code == 2 and "stop after the call" in r.output
    assert seen["options"].open_set is True


def test_evaluate_open_set_of_a_model_folder_uses_its_model_kind_and_window_spec(windows_file, tmp_path):
    runner = CliRunner()
    model = tmp_path / "m"
    r = runner.invoke(app, ["train", "--data", str(windows_file), "--model", "hgb", "--folds", "3", "--no-members",
                            "--no-ablation", "--out", str(model), "-q"])
    assert r.exit_code == 0, r.output
    r = runner.invoke(app, ["evaluate", str(model), "--open-set", "--data", str(windows_file), "--folds", "3",
                            "--out", str(tmp_path / "rep"), "-q"])
    assert r.exit_code == 0, r.output
    doc = json.loads((tmp_path / "rep" / "open_set.json").read_text())
    manifest = json.loads((model / "manifest.json").read_text())
    assert doc["model"] == manifest["default_model"] == "hgb" and doc["model_dir"] == str(model)
    assert doc["window_spec"] == manifest["window_spec"]["name"]
    r = runner.invoke(app, ["evaluate", str(model), "--open-set", "--data", str(windows_file), "--windows", "state"])
    assert r.exit_code == 2 and "--windows" in r.output


def test_train_novelty_false_alarm_sets_the_served_threshold(windows_file, tmp_path):
    """``train --novelty-false-alarm``: the manifest states the target, and a higher target puts the
    served threshold lower (flags more windows); a target outside (0, 0.5) is refused."""
    from terrainml.models.artifacts import load_artifact
    from terrainml.models.novelty import DEFAULT_FALSE_ALARM

    runner = CliRunner()
    common = ["train", "--data", str(windows_file), "--model", "svm", "--folds", "3", "--no-ablation",
              "--no-members", "-q"]
    thresholds, targets = {}, {}
    for target in (None, 0.2):
        out = tmp_path / f"m{target}"
        extra = [] if target is None else ["--novelty-false-alarm", str(target)]
        r = runner.invoke(app, common + ["--out", str(out)] + extra)
        assert r.exit_code == 0, r.output
        targets[target] = json.loads((out / "manifest.json").read_text())["novelty"]["false_alarm_target"]
        thresholds[target] = load_artifact(out).novelty.threshold
    assert targets == {None: DEFAULT_FALSE_ALARM, 0.2: 0.2}
    assert thresholds[0.2] < thresholds[None]
    r = runner.invoke(app, common + ["--out", str(tmp_path / "bad"), "--novelty-false-alarm", "0.7"])
    assert r.exit_code == 2 and "--novelty-false-alarm must be in (0, 0.5)" in r.output


def test_evaluate_open_set_takes_the_novelty_false_alarm_target(windows_file, tmp_path):
    out = tmp_path / "rep"
    r = CliRunner().invoke(app, ["evaluate", "--open-set", "--data", str(windows_file), "--folds", "3",
                                 "--novelty-false-alarm", "0.2", "--out", str(out), "-q"])
    assert r.exit_code == 0, r.output
    assert json.loads((out / "open_set.json").read_text())["settings"]["false_alarm_target"] == 0.2
    r = CliRunner().invoke(app, ["evaluate", "--open-set", "--data", str(windows_file), "--novelty-false-alarm", "0"])
    assert r.exit_code == 2 and "--novelty-false-alarm must be in (0, 0.5)" in r.output
