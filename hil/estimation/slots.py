"""What the compiled estimation kernels share, written once: the :class:`~hil.estimation.sensors.StepFlag`
bits as plain ints, and the one way a kernel's parameter array is packed from its settings (:func:`pack`).

The kernels (:mod:`.variational`, :mod:`.chain`, :mod:`.prefilter`, :mod:`.magnetic`, :mod:`.motion`) take
their parameters and state as flat float64 arrays whose slots are named by module constants (``P_*``,
``CP_*``, ``SP_*``, ``GP_*``, ``MP_*``): numba's dispatcher costs ~0.1 µs per argument, and a live step has a
few µs, so a step takes two or three arrays rather than a dozen dataclass fields. Each module keeps its own
layout and its own checks of the settings; the filling of the array is here.

The flags are ints because a kernel tests ``code & NEWTON_FAILED`` on an int (numba compiles a module
global int as a constant, an ``IntFlag`` member not at all); their values are ``StepFlag``'s by
construction. Pure math, no I/O."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.estimation.sensors import StepFlag

Array = NDArray[np.float64]

GYR_STALE = int(StepFlag.GYR_STALE)
ACC_STALE = int(StepFlag.ACC_STALE)
MAG_STALE = int(StepFlag.MAG_STALE)
GAP = int(StepFlag.GAP)
FAILOVER = int(StepFlag.FAILOVER)
DEGENERATE = int(StepFlag.DEGENERATE)
NEWTON_FAILED = int(StepFlag.NEWTON_FAILED)
SUBSTEPPED = int(StepFlag.SUBSTEPPED)
MAG_DISTURBED = int(StepFlag.MAG_DISTURBED)
REST = int(StepFlag.REST)

GYRO_LIMIT = 1e4
"""rad/s: a rate reading beyond this on any axis is not usable to the estimator (as NaN is). MEMS rate
sensors read at most ~35 rad/s (a phone's ±2000 °/s) to ~350 rad/s; 1e4 rad/s (~95 000 rpm) is beyond
every one, and far below where a step's arithmetic overflows (~1e154 rad/s, the square of a rate)."""
MAX_SUBSTEPS = 1 << 20
"""Sub-steps the estimator splits a step into at most (~0.15 s of compute): at the default ``max_step_s``
of 0.05 s a step of up to 14.6 h. A longer one is no gap a phone's stream has, but a far timestamp."""


def pack(size: int, slots: Mapping[int, float | ArrayLike]) -> Array:
    """A parameter array of ``size`` float64 slots, zero but where ``slots`` says: slot index → a number,
    or anything array-like, written flattened (row-major: a 3×3 matrix takes nine slots) from that slot
    on. ValueError for a slot, or a run of slots, outside the array (a layout and its packer that
    disagree: a bug, caught where the array is built rather than read as zeros by a kernel)."""
    out = np.zeros(size)
    for slot, value in slots.items():
        flat = np.asarray(value, dtype=float).reshape(-1)
        if not (0 <= slot and slot + flat.size <= size):
            raise ValueError(f"slots {slot}..{slot + flat.size - 1} lie outside an array of {size}")
        out[slot : slot + flat.size] = flat
    return out
