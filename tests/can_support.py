"""CAN buses for tests: fresh ``virtual`` channels, and ``udp_multicast`` groups and whether this machine
can carry IPv4 multicast at all (:mod:`bench.can_bus`; a sandbox without a multicast route cannot: its
tests are then skipped with that reason, through the ``udp_multicast`` marker in tests/conftest.py — and
CI, which sets ``VSCMG_HIL_REQUIRE_ALL=1``, fails instead of skipping)."""

from __future__ import annotations

import itertools
import os
from typing import Any

from bench.can_bus import multicast_url, udp_multicast_problem

_channels = itertools.count()


def read_until(transport: Any, n_frames: int, tries: int = 50) -> bytes:
    """What ``transport`` (a :class:`~hil.link.transports.can_bus.CanTransport`) reads until ``n_frames``
    frames' delimiters are in (or ``tries`` reads of 20 ms)."""
    got = b""
    for _ in range(tries):
        got += transport.read(0.02)
        if got.count(0) >= n_frames:
            break
    return got


def virtual_url(fd: bool = False, node: int = 5) -> str:
    """A ``can://virtual/...`` URL on a channel no other test in this process uses."""
    return f"can://virtual/test-{os.getpid()}-{next(_channels)}?node={node}&fd={int(fd)}"


__all__ = ["multicast_url", "read_until", "udp_multicast_problem", "virtual_url"]
