"""What ``train`` and ``evaluate`` read, shared by both: the data (a windows file or a folder of
logs), the run tables of a folder, and the options both commands offer.

Exit codes as every command's: 2 with a message naming the file or the option, never a traceback.
"""

from __future__ import annotations

from pathlib import Path

from terrainml.commands._common import console, fail, is_windows_file, open_dataset
from terrainml.models.novelty_target import check_false_alarm

TRUSTED_KEY_HELP = ("Public key (KEY.pub from 'terrainml model keygen'); the model folder must be signed by "
                    "it ('terrainml model sign'), else it is refused. Repeat for several.")
NOVELTY_FALSE_ALARM_HELP = ("Target share of moving windows on known ground over the novelty threshold (held-out "
                            "training runs): higher finds more unknown ground and serves more known ground the "
                            "safe cap (unknown_terrain). In (0, 0.5).")


def check_novelty_false_alarm_option(novelty_false_alarm: float) -> None:
    """``--novelty-false-alarm`` checked by the novelty module's own rule (one definition of the range)."""
    try:
        check_false_alarm(novelty_false_alarm)
    except ValueError:
        fail(f"--novelty-false-alarm must be in (0, 0.5), e.g. 0.05, got {novelty_false_alarm}")


def load_data(data: Path, *, robot, preset: str, n_jobs: int, dask_address, fmt: str, spec=None,
              quiet: bool = False, sensors=None):
    """A Dataset from a windows Parquet or (built first) a folder of logs."""
    if is_windows_file(data):
        return open_dataset(data)
    from terrainml.commands.dataset_cmds import build_with_progress, print_class_report, rejection_table

    ds = build_with_progress(data, robot=robot, preset=preset, n_jobs=n_jobs, dask_address=dask_address,
                             fmt=fmt, quiet=quiet, spec=spec, sensors=sensors)
    if not quiet:
        console.print(rejection_table(ds))
        print_class_report(ds)
    return ds


def load_tables(data: Path, *, robot, fmt: str, quiet: bool, progress=None, n_jobs: int = 1):
    """(ingested run tables, RobotSpec) of a folder of logs or a BorealTC folder; ``progress``
    gets the stage ``logs`` (per log; BorealTC: the folder at once); ``n_jobs``: logs read at once."""
    from terrainml.commands._common import open_robot
    from terrainml.pipeline.progress import report

    if fmt == "borealtc":
        from terrainml.pipeline.dataset import borealtc_tables

        rb = open_robot(robot or "husky")
        say = None if quiet else (lambda msg: console.print(msg, highlight=False))
        report(progress, "logs", 0, None, "", f"reading the BorealTC folder {data}")
        return borealtc_tables(data, rb, say), rb
    if fmt != "auto":
        fail(f"unknown --format {fmt!r}; expected auto or borealtc")
    from terrainml.pipeline.dataset import find_logs, ingest_logs

    rb = open_robot(robot)
    logs = find_logs(data)
    report(progress, "logs", 0, len(logs), "logs", f"reading {len(logs)} logs of {data}")
    tables, bad = ingest_logs(logs, rb, n_jobs=n_jobs,
                              progress=lambda k, n, name: report(progress, "logs", k, n, "logs", name))
    if bad:
        console.print(f"[yellow]warning:[/] {len(bad)} log(s) unusable, left out: {'; '.join(bad[:5])}"
                      + (" ..." if len(bad) > 5 else ""), highlight=False)
    return tables, rb


def check_sensors(ds, sensors) -> None:
    """A windows file already has its channels: refuse ``--sensors`` that it does not match."""
    extra = [g for g in ds.sensors if g not in sensors]
    if extra:
        fail(f"the windows use sensor groups {ds.sensors}, not only {sensors}; rebuild them with "
             f"`terrainml dataset build ... --sensors {','.join(sensors)}`")
