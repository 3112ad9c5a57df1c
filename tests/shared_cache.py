"""Files built once per test session for every pytest-xdist worker (a cache directory with a file lock).

Session fixtures run once per *worker*: with ``pytest -n 2`` each worker would write the same
logs or train the same model. :func:`shared_dir` builds a folder once, under the session's base
temporary directory that all workers share (the parent of each worker's ``basetemp``), behind a
:class:`filelock.FileLock`; the other workers wait for it and read the same files. This is the
recipe of the pytest-xdist documentation ("Making session-scoped fixtures execute only once").
Only files are shared (never pickles): a fixture loads what it needs from the folder.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Callable

from filelock import FileLock


def shared_dir(tmp_path_factory, name: str, build: Callable[[Path], object]) -> Path:
    """The folder ``name``, built by ``build(folder)`` once for the whole session.

    Parameters
    ----------
    tmp_path_factory : pytest's session fixture.
    name : folder name, unique per cached artefact.
    build : writes the folder's content (called with an empty folder, at most once per session).

    Returns
    -------
    Path of the built folder (complete: a build that raised leaves no folder behind).
    """
    root = tmp_path_factory.getbasetemp()
    if root.name.startswith("popen-gw"):        # an xdist worker: share its parent, the session's
        root = root.parent
    out = root / f"shared-{name}"
    with FileLock(str(out) + ".lock"):
        if not (out / ".complete").is_file():
            if out.exists():
                shutil.rmtree(out)
            out.mkdir(parents=True)
            try:
                build(out)
            except BaseException:
                shutil.rmtree(out, ignore_errors=True)
                raise
            (out / ".complete").touch()
    return out
