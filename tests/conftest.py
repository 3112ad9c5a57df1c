"""Shared test setup: ``tests/`` on ``sys.path`` so area folders can import shared helpers
(``synthetic_runs``, ``shared_cache``) by module name; one BLAS/OpenMP thread per test process,
and one job for ``terrainml train`` (``TERRAINML_N_JOBS``; its default is every core).

``make test`` runs one pytest-xdist worker per core, so a library thread pool per worker
(OpenMP in sklearn's boosted trees, BLAS, torch) only oversubscribes the cores.
"""

import os
import sys
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # before numpy, sklearn or torch are imported; subprocesses inherit it
os.environ.setdefault("TERRAINML_N_JOBS", "1")  # the workers already use every core

_TESTS = str(Path(__file__).resolve().parent)
if _TESTS not in sys.path:
    sys.path.insert(0, _TESTS)
