"""Helpers shared by the command modules, written once (design §15).

Every refusal goes through :func:`fail`: one red ``error:`` line on stderr that names the file
(or the option), exit code 2, never a traceback. Outputs and ``--n-jobs`` are checked with
:func:`check_output_writable` and :func:`check_n_jobs` *before* any long work, so a bad target
is refused in a second rather than after the simulation or the estimation.

Only typer and rich are imported here; the robot specs (numpy, yaml), the readers (pyarrow, the
ingest engine, the dataset pipeline) are imported inside the helpers, so that ``terrainml --help``,
``terrainml version`` and every ``--help`` import none of them (``tests/test_cli_startup.py``).
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, NoReturn

import typer
from rich.console import Console
from rich.markup import escape

from terrainml.atomic import DISK_ERRNOS, OutputWriteError

if TYPE_CHECKING:
    from terrainml.robot import RobotSpec

__all__ = ["EXIT_USAGE", "check_n_jobs", "check_output_writable", "console", "fail", "failure_message",
           "is_windows_file", "open_dataset", "open_dataset_spec", "open_robot", "open_run"]

#: Exit code of every refusal (bad option, unreadable input, unwritable output).
EXIT_USAGE = 2

# Messages and progress bars go to stderr so that stdout stays machine-readable (JSON, tables).
console = Console(stderr=True, soft_wrap=True)


def fail(msg: str) -> NoReturn:
    """Print ``error: msg`` in red on stderr and exit with code 2.

    ``msg`` is escaped, so a path or a value holding ``[...]`` is printed as is, not read as
    rich markup.
    """
    console.print(f"[red]error:[/] {escape(msg)}", highlight=False)
    raise typer.Exit(EXIT_USAGE)


def failure_message(source: object, exc: BaseException, out: object = None) -> str:
    """The ``error:`` line for an unexpected failure of a command reading ``source``.

    Parameters
    ----------
    source : object
        The command's input, named for any failure that is not a failed write.
    exc : BaseException
        The failure.
    out : object, optional
        The command's output, named for a full disk's bare ``OSError`` that names no file.

    Returns
    -------
    str
        A failed write names its output (:class:`terrainml.atomic.OutputWriteError`, or an
        ``OSError`` of :data:`terrainml.atomic.DISK_ERRNOS`); anything else the input and the
        exception.
    """
    if isinstance(exc, OutputWriteError):
        return str(exc)
    if isinstance(exc, OSError) and exc.errno in DISK_ERRNOS:
        return f"{exc.filename or out or 'an output'}: cannot write ({exc.strerror or exc})"
    return f"{source}: {type(exc).__name__}: {exc}"


def open_robot(robot: str | Path | RobotSpec | None) -> RobotSpec:
    """:func:`terrainml.robot.load_robot`, refusing a bad spec with its message (names the file)."""
    from terrainml.robot import RobotSpecError, load_robot

    try:
        return load_robot(robot)
    except RobotSpecError as exc:
        fail(str(exc))


#: the option that lets a dataset spec read outside the dataset folder (``../imu_{run}.csv``)
ALLOW_OUTSIDE_HELP = ("Let the dataset spec's file patterns and label file reach outside the dataset "
                      "folder (absolute, ~ or ..); refused by default.")


def open_dataset_spec(fmt: str | None, allow_outside: bool):
    """``--format`` with ``--allow-outside-spec-dir``: the spec parsed with permission to read
    outside its folder (a refusal names the spec); without the flag ``fmt`` passes as is and the
    reader refuses such a spec itself."""
    if fmt is None or not allow_outside:
        return fmt
    from terrainml.io.ingest.dataset_spec import DatasetSpecError, load_dataset_spec

    try:
        return load_dataset_spec(fmt, allow_outside=True)
    except DatasetSpecError as exc:
        fail(str(exc))


def open_run(path: Path, *, robot: str | Path | RobotSpec | None = None, topics: str | None = None):
    """The canonical run table (contract 1) of a run Parquet or a log.

    Parameters
    ----------
    path : a canonical run table (``.parquet``, read and validated as written) or a log
        (``.mcap``, ``.bag``, ``.csv``) ingested onto the base-rate grid.
    robot : robot spec for ingesting a log (built-in name, YAML path or spec; default the
        reference robot). Ignored for a run Parquet, which carries its own.
    topics : topic map (built-in name or YAML path) for an ``.mcap``/``.bag`` log.

    Returns
    -------
    pandas.DataFrame, one row per tick, metadata in ``attrs['terrainml']``. A missing,
    unreadable or unusable input exits with code 2 and a message naming ``path``.
    """
    path = Path(path)
    if not path.exists():
        fail(f"{path}: file not found")
    if not path.is_file():
        fail(f"{path}: not a file (expected a run table or a log)")
    if path.suffix.lower() == ".parquet":
        from terrainml.schema import SchemaError, read_run_parquet

        try:
            return read_run_parquet(path)
        except SchemaError as exc:  # the message names the file
            fail(str(exc))
    from terrainml.io.ingest import load_run

    robot = open_robot(robot)
    try:
        res = load_run(path, robot=robot, topic_map=topics)
    except Exception as exc:  # noqa: BLE001 - any reader error becomes a message naming the file
        fail(f"{path}: cannot read run: {exc}")
    if not res.report.usable:
        # the ingest errors usually start with the path already: say it once
        why = "; ".join(e.removeprefix(f"{path}: ") for e in res.report.errors) or "no usable sensor data"
        fail(f"{path}: log not usable: {why}")
    return res.table


def is_windows_file(path: Path) -> bool:
    """True when ``path`` is a Parquet file carrying the windows metadata of ``dataset build``."""
    path = Path(path)
    if not (path.is_file() and path.suffix.lower() == ".parquet"):
        return False
    import pyarrow.parquet as pq

    from terrainml.pipeline.dataset import META_KEY

    try:
        return META_KEY in (pq.read_schema(path).metadata or {})
    except Exception:  # noqa: BLE001 - not readable as Parquet: not a windows file
        return False


def open_dataset(path: Path):
    """The window dataset written by ``terrainml dataset build`` (fingerprint verified).

    Returns a :class:`terrainml.pipeline.dataset.Dataset`; a missing or foreign file exits with
    code 2 and a message naming it.
    """
    from terrainml.pipeline.dataset import DatasetError, read_windows

    try:
        return read_windows(path)
    except DatasetError as exc:  # the message names the file
        fail(str(exc))


def check_output_writable(path: Path, *, folder: bool = False) -> Path:
    """Refuse, before any long work, an output that cannot be created and written.

    Parameters
    ----------
    path : the output file (or, with ``folder=True``, the output folder).
    folder : whether ``path`` is a folder the command writes into.

    Nothing is left behind: a missing output is checked through its nearest existing
    ancestor, which must be a folder where a file can be created (an anonymous temporary
    file, removed at once); the writers create the missing folders later. An existing output
    file is opened for appending, which changes neither its content nor its mtime. Refusals
    exit with code 2 and name ``path``.

    Returns
    -------
    ``path`` as a :class:`~pathlib.Path`.
    """
    path = Path(path)
    what = "folder" if folder else "file"
    if path.exists():
        if path.is_dir() != folder:
            fail(f"{path}: exists and is not a {what}")
        if not folder:
            try:
                with path.open("ab"):
                    pass
            except OSError as exc:
                fail(f"{path}: cannot write the output {what} ({exc.strerror or exc})")
            return path
        probe = path
    else:
        probe = path.parent
        while not probe.exists() and probe != probe.parent:
            probe = probe.parent
        if not probe.is_dir():
            fail(f"{path}: cannot create the output {what}: {probe} is not a folder")
    try:
        with tempfile.TemporaryFile(dir=probe):
            pass
    except OSError as exc:
        where = "" if probe == path else f" in {probe}"
        fail(f"{path}: cannot write the output {what}{where} ({exc.strerror or exc})")
    return path


def check_n_jobs(n_jobs: int, option: str = "--n-jobs") -> int:
    """Refuse a joblib job count other than >= 1 or -1 (all cores); returns ``n_jobs``."""
    if n_jobs == 0 or n_jobs < -1:
        fail(f"{option} must be >= 1, or -1 for all cores; got {n_jobs}")
    return n_jobs
