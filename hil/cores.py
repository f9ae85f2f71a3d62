"""How many cores this process may use: what "one per core" means wherever hil sizes parallel work (a
campaign's local workers, the processes that draw a run's figures). A process confined to some cores
(``taskset``, a container's CPU set) gets as many as it may run on, not as many as the machine has."""

from __future__ import annotations

import os


def available_cores() -> int:
    """The cores this process may run on (its CPU affinity where the OS says, else the machine's), ≥ 1."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return os.cpu_count() or 1
