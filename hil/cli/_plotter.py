"""``python -m hil.cli._plotter``: draw a run directory's figures in a process of its own. ``hil run``
starts it before the run, so matplotlib is imported, and a first figure drawn and thrown away
(:func:`hil.plots.run.warm`), on another core while the run runs; it then reads the
run directory's path from stdin (:func:`read_run_dir`; nothing: nothing to draw), draws ``plots/`` (shared
among forked processes, one per core: :mod:`hil.plots.forked`) and prints ``name: path`` per figure. A
drawing error is printed to stderr with exit status 2 — also one in importing matplotlib or drawing the
first figure, said only once the run directory is read: a plotter that died at its imports left ``hil
run`` a closed pipe to write to (a BrokenPipeError's traceback after a run that had completed)."""

from __future__ import annotations

import os
import sys
from typing import BinaryIO

from hil.cores import available_cores
from protocol.errors import HilError


def main() -> int:
    try:
        from hil.plots.run import plot_run, warm

        warm()  # while the run runs: its figures then draw on warm caches
    except Exception as exc:  # no figures can be drawn here: said after the run, not a dead pipe during it
        read_run_dir(sys.stdin.buffer)
        print(f"plots: cannot draw figures: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 2
    run_dir = read_run_dir(sys.stdin.buffer)
    if not run_dir:
        return 0
    try:
        paths = plot_run(run_dir, processes=available_cores())
    except HilError as exc:
        print(f"plots: {exc}", file=sys.stderr)
        return 2
    for name, path in paths.items():
        print(f"{name}: {path}")
    return 0


def read_run_dir(stream: BinaryIO) -> str:
    """The run directory's path as ``hil run`` hands it over: everything to the end of input (the run closes
    the pipe after it), less the one line break that ends it, decoded as the file system names files
    (:func:`os.fsdecode`); "" when nothing came. A path is any bytes but NUL: the first line stripped of
    spaces at both ends drew the figures of another directory, or none ("no such file"), for a run whose
    ``--out`` began or ended with a space, and a line break inside it cut it there."""
    data = stream.read()
    return os.fsdecode(data[:-1] if data.endswith(b"\n") else data)


if __name__ == "__main__":
    sys.exit(main())
