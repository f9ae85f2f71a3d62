"""``python -m hil.cli._plotter``: draw a run directory's figures in a process of its own. ``hil run``
starts it before the run, so matplotlib is imported, and a first figure drawn and thrown away
(:func:`hil.plots.run.warm`), on another core while the run runs; it then reads the
run directory's path from stdin (an empty line or end of input: nothing to draw), draws ``plots/`` (shared
among forked processes, one per core: :mod:`hil.plots.forked`) and prints ``name: path`` per figure. A
drawing error is printed to stderr with exit status 2."""

from __future__ import annotations

import sys

from hil.cores import available_cores
from hil.plots.run import plot_run, warm
from protocol.errors import HilError


def main() -> int:
    warm()  # while the run runs: its figures then draw on warm caches
    run_dir = sys.stdin.readline().strip()
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


if __name__ == "__main__":
    sys.exit(main())
