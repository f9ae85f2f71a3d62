"""Figures (matplotlib, Agg canvas: no display and no pyplot global state, safe in threads and tests).

Importing this package imports matplotlib with the environment's ``MPLBACKEND`` set aside
(:func:`_import_matplotlib`): every figure here is drawn on an Agg canvas of its own, never through a
backend, but matplotlib checks that variable as it is imported and raises ValueError for a name it does not
know (a typo, ``MPLBACKEND=Agg2``): ``hil report`` ended in that traceback, and ``hil run``'s plotter died
before its run ended (the run's own exit a BrokenPipeError's traceback, no summary printed)."""

from __future__ import annotations

import os
import sys


def _import_matplotlib() -> None:
    """matplotlib imported whatever ``MPLBACKEND`` says (none of its backends draws these figures); the
    variable is put back at once, for a process this one starts."""
    if "matplotlib" in sys.modules:
        return
    backend = os.environ.pop("MPLBACKEND", None)
    try:
        import matplotlib  # noqa: F401 — imported here, without the variable
    finally:
        if backend is not None:
            os.environ["MPLBACKEND"] = backend


_import_matplotlib()
