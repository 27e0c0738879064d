"""numba compilation with an on-disk cache where one can be written (the hot kernels of the agent and the traffic)."""

from __future__ import annotations

from collections.abc import Callable

import numba


def jit(fn: Callable) -> Callable:
    """numba.njit with an on-disk cache where a writable cache location exists, else compiled once per process."""
    try:
        return numba.njit(cache=True, error_model="numpy")(fn)
    except RuntimeError:  # no cache locator: read-only install and no writable user cache dir (NUMBA_CACHE_DIR)
        return numba.njit(cache=False, error_model="numpy")(fn)
