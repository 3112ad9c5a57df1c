"""numba's ``njit`` when numba is importable, else a no-op decorator (one shim for all kernels).

``HAVE_NUMBA`` tells which. Set ``TERRAINML_NO_NUMBA=1`` to force the pure-Python path (tests of
the fallback, or platforms without numba wheels); numba is a dependency, so the compiled path is
the normal one.
"""

from __future__ import annotations

import os

try:  # pragma: no cover - depends on the environment
    if os.environ.get("TERRAINML_NO_NUMBA"):
        raise ImportError("disabled by TERRAINML_NO_NUMBA")
    from numba import njit

    HAVE_NUMBA = True
except Exception:  # pragma: no cover
    HAVE_NUMBA = False

    def njit(*args, **kwargs):
        """No-op stand-in for ``numba.njit`` (with or without arguments)."""
        if args and callable(args[0]):
            return args[0]
        return lambda f: f

__all__ = ["HAVE_NUMBA", "njit"]
