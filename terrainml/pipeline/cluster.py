"""Joblib work on a Dask cluster (design §14): the logs of a dataset build, the fits of ``train``.

Every parallel loop of the chain is a joblib ``Parallel`` (:func:`terrainml.pipeline.dataset.
build_dataset` over logs, :func:`terrainml.evaluation.cv.cross_validate` and
:func:`~terrainml.evaluation.cv.predict_held_out` over fits). Inside :func:`dask_jobs` they run
on the cluster of a ``distributed.Client`` through ``joblib.parallel_config(backend="dask")``:
the cluster's threads set the parallelism (the callers' ``n_jobs`` is not used), large
arguments (the windows) are scattered to the workers once per ``Parallel``, and results come
back in order, so the figures are the same as on one machine with the same seed.
"""

from __future__ import annotations

import os
from contextlib import contextmanager
from typing import Any, Iterator

from joblib import parallel_config

__all__ = ["dask_jobs", "ClusterError", "cluster_summary", "worker_env_note", "CONNECT_TIMEOUT_S", "MALLOC_TRIM_VAR"]

#: s to wait for the scheduler (distributed retries a refused connection until then)
CONNECT_TIMEOUT_S = 30.0
#: glibc's trim threshold, which Dask's nanny sets in every worker it starts (64 KiB by default,
#: config ``distributed.nanny.pre-spawn-environ``). Setting it at all also fixes glibc's mmap
#: threshold, so every large temporary array of a fit is mapped and unmapped anew: the boosted
#: trees' fits ran 1.6x slower in such workers (BENCHMARKS.md "Scaling on Dask").
MALLOC_TRIM_VAR = "MALLOC_TRIM_THRESHOLD_"


class ClusterError(RuntimeError):
    """The Dask scheduler cannot be reached (the message names its address)."""


@contextmanager
def dask_jobs(address: str | None, timeout_s: float | None = None) -> Iterator[Any]:
    """Run the joblib work inside on the Dask cluster at ``address``; None: on this machine.

    Parameters
    ----------
    address : ``tcp://HOST:PORT`` of a Dask scheduler, or None (nothing changes).
    timeout_s : s to wait for the connection (default :data:`CONNECT_TIMEOUT_S`).

    Yields
    ------
    The ``distributed.Client`` (None without an address). Raises :class:`ClusterError` when
    the scheduler cannot be reached.
    """
    if not address:
        yield None
        return
    from distributed import Client  # noqa: PLC0415 - dask, imported only when used

    try:
        client = Client(address, timeout=f"{CONNECT_TIMEOUT_S if timeout_s is None else timeout_s:g}s")
    except (OSError, ValueError, TypeError) as exc:  # refused, timed out, malformed address
        raise ClusterError(f"cannot reach the Dask scheduler at {address!r} ({type(exc).__name__}: {exc})") from None
    with client, parallel_config(backend="dask"):
        yield client


def cluster_summary(client: Any) -> str:
    """``"N workers, M threads"`` of a connected client."""
    cores = client.ncores()
    return f"{len(cores)} worker(s), {sum(cores.values())} thread(s)"


def _malloc_trim_setting() -> str | None:
    return os.environ.get(MALLOC_TRIM_VAR)


def worker_env_note(client: Any) -> str:
    """A ``note:`` naming how many workers set :data:`MALLOC_TRIM_VAR` and how to unset it, or ""."""
    settings = client.run(_malloc_trim_setting)
    slow = sorted(w for w, v in settings.items() if v is not None)
    if not slow:
        return ""
    return (f"note: {len(slow)} of {len(settings)} Dask workers run with {MALLOC_TRIM_VAR} set (Dask's default), "
            "which makes the boosted trees' fits about 1.6x slower; start them with "
            f"distributed.nanny.pre-spawn-environ.{MALLOC_TRIM_VAR} set to null in their Dask config "
            "(docs/models.md)")
