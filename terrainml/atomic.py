"""Outputs written whole or not at all, and a write failure named by its output (design §3).

Every file a command writes goes to a hidden ``.NAME.part`` beside it and is renamed onto
``NAME`` only once complete, so a full disk, a quota, a read-only remount or a crash never leave
a partial file that looks complete. A failure while writing raises :class:`OutputWriteError`: an
``OSError`` whose ``filename`` is the output (a bare ``write()`` ENOSPC names no file) and whose
message says nothing was written; the CLI prints it as one ``error:`` line (exit 2, no traceback).

A folder of several files (a model folder: models, members, report, manifest) is written the same
way (:func:`staged_folder`): under a hidden ``.NAME.partial-PID/NAME`` beside it, renamed onto
``NAME`` only once complete, so a reader (``terrainml predict``) never opens half of one.
"""

from __future__ import annotations

import errno
import os
import shutil
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

#: errno values that mean "the output could not be written" rather than "the input is bad"
DISK_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS})


class OutputWriteError(OSError):
    """Writing the output ``filename`` failed (full disk, quota, read-only, ...); nothing was left."""

    def __str__(self) -> str:
        return f"{self.filename}: cannot write the output ({self.strerror}); nothing was written"


def part_path(path: str | Path) -> Path:
    """The hidden temporary name ``.NAME.part`` beside ``path``.

    Parameters
    ----------
    path : str or pathlib.Path
        The final output.

    Returns
    -------
    pathlib.Path
        ``.NAME.part`` in the same folder (same file system, so the rename is atomic).
    """
    path = Path(path)
    return path.with_name(f".{path.name}.part")


def output_error(exc: OSError, path: str | Path) -> OutputWriteError:
    """``exc`` (raised while writing ``path``) as an :class:`OutputWriteError` naming ``path``.

    Parameters
    ----------
    exc : OSError
        The failure (a bare ``write()`` ENOSPC, an Arrow ``OSError`` without errno, ...).
    path : str or pathlib.Path
        The output being written.

    Returns
    -------
    OutputWriteError
        ``exc`` itself when it already is one, else a new one (errno EIO when ``exc`` has none).
    """
    if isinstance(exc, OutputWriteError):
        return exc
    return OutputWriteError(exc.errno or errno.EIO, exc.strerror or str(exc), str(path))


def discard(tmp: Path) -> None:
    """Remove a temporary output (never raises: the write error is the one to report)."""
    try:
        tmp.unlink(missing_ok=True)
    except OSError:
        pass


@contextmanager
def atomic_output(path: str | Path) -> Iterator[Path]:
    """Yield the temporary path to write; rename it onto ``path`` on success.

    Parameters
    ----------
    path : str or pathlib.Path
        The final output; its parent folder is created.

    Yields
    ------
    pathlib.Path
        ``.NAME.part`` beside ``path``, to be written by the block.

    Raises
    ------
    OutputWriteError
        An ``OSError`` in the block or the rename, naming ``path``. On any exception the temporary
        file is removed and nothing is left at ``path``.
    """
    path = Path(path)
    tmp = part_path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        yield tmp
        os.replace(tmp, path)
    except OSError as exc:
        discard(tmp)
        raise output_error(exc, path) from None
    except BaseException:
        discard(tmp)
        raise


def publish_folder(src: str | Path, dest: str | Path) -> Path:
    """Rename the complete folder ``src`` onto ``dest`` (same file system); an existing ``dest`` is
    moved aside first and removed after, so ``dest`` is only ever the old folder or the new one.

    Returns
    -------
    pathlib.Path
        ``dest``.
    """
    src, dest = Path(src), Path(dest)
    old = None
    if dest.exists():
        old = dest.with_name(f".{dest.name}.old-{os.getpid()}")
        shutil.rmtree(old, ignore_errors=True)
        os.replace(dest, old)
    os.replace(src, dest)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
    return dest


@contextmanager
def staged_folder(path: str | Path) -> Iterator[Path]:
    """Yield a folder to write, named like ``path`` inside a hidden ``.NAME.partial-PID`` beside
    it; on success it is renamed onto ``path`` (:func:`publish_folder`), on any exception removed.

    The folder keeps ``path``'s name while it is written (reports name it), and a process that
    reads ``path`` meanwhile sees the previous folder or none, never a partial one. The caller may
    publish the staged folder elsewhere before raising (e.g. a refusal's report).

    Yields
    ------
    pathlib.Path
        ``.NAME.partial-PID/NAME`` (not created: the writer creates it).
    """
    path = Path(path)
    stage = path.parent / f".{path.name}.partial-{os.getpid()}"
    shutil.rmtree(stage, ignore_errors=True)
    stage.mkdir(parents=True)
    try:
        yield stage / path.name
        if (stage / path.name).exists():
            publish_folder(stage / path.name, path)
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` whole or not at all (:func:`atomic_output`).

    Parameters
    ----------
    path : str or pathlib.Path
        The output file.
    text : str
        Its content (UTF-8).

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    OutputWriteError
        The write failed (full disk, quota, read-only); nothing is left at ``path``.
    """
    with atomic_output(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)
