"""Compiled kernels: the project's one switch between compiled and interpreted numerics.

Each hot kernel (the plant step, the drive models, the simulated phone, the estimator's inner loop,
steering's pseudo-inverse) is written once, in the subset of Python that numba compiles, and decorated
with :func:`kernel`; its numpy reference lives beside it and the tests compare the two. numba compiles a
kernel on its first call and caches the machine code on disk (``cache=True``: ``__pycache__`` beside the
source, or ``NUMBA_CACHE_DIR``), so only a fresh install's first run pays for compiling.

``NUMBA_DISABLE_JIT=1`` (numba's own switch) turns every kernel back into the plain Python it is written
in: slower, but steppable in a debugger, with Python's tracebacks. :data:`COMPILED` says which is in force.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar, cast

import numba

F = TypeVar("F", bound=Callable[..., Any])

COMPILED: bool = not getattr(numba.config, "DISABLE_JIT", False)
"""False when ``NUMBA_DISABLE_JIT=1``: every kernel runs as plain Python."""


def kernel(fn: F) -> F:
    """Compile ``fn`` in nopython mode, cached on disk, releasing the GIL while it runs (so a world thread
    and the host's control loop can run side by side in real time)."""
    return cast(F, numba.njit(cache=True, nogil=True)(fn))


__all__ = ["COMPILED", "kernel"]
