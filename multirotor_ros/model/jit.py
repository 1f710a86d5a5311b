"""Small scalar kernels compiled by numba on first use, for arithmetic on a few short arrays per call.

In numpy each operation on an array of a few elements costs about a microsecond of call overhead, so a
function of a few dozen of them (an IMU sample, an allocation) is dominated by the calls; the same
function written as scalar loops and compiled costs a few microseconds in all. numba is imported only on
first use: the modules that merely define such kernels (and the nodes that import them for their types)
never pay its start-up. Compiled code goes to numba's disk cache (``cache=True``), so a process after
the first loads it instead of compiling.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

_COMPILED: dict[Callable[..., Any], Callable[..., Any]] = {}


def kernel(function: Callable[..., Any]) -> Callable[..., Any]:
    """``function`` compiled by numba (once per process; from numba's disk cache after the first)."""
    compiled = _COMPILED.get(function)
    if compiled is None:
        from numba import njit

        compiled = _COMPILED[function] = njit(cache=True, error_model="numpy")(function)
    return compiled
