"""Every board server's judgement of host presence against a stall of its own process at *any* point of
its serving loop, not only where the loop waits for input.

CI met it: ``firmware-sim --can`` SIGSTOPped for 1.5 s while a host streamed heartbeats said "host left"
on waking, then "host connected again" — its loop judged the silence before it looked at the frames
that had waited on the bus. The loops now judge silence only as of the start of a look at the link that
found nothing (:meth:`firmware_sim.servers.base.HostPresence.tick`).

Lockstep and in-process: the board's clock moves a little at each read and jumps by a stall at its
``at``-th read — wherever in the loop that read is — while the host, talking every ``PERIOD_S`` of
board time, speaks once more in the stall. Its bytes are waiting when the loop goes on: the host never
left. A host that was silent through the stall is gone once and back once. The real transports: a
``virtual`` CAN bus and a real pty.
"""

from __future__ import annotations

import math
import os
import select
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import hypothesis.strategies as st
import pytest
from can_support import virtual_url
from hypothesis import given, settings

from firmware_sim.board import Board
from firmware_sim.board.config import BoardConfig
from firmware_sim.servers.base import HOST_SILENCE_S, BoardServer
from firmware_sim.servers.can_server import CanServer
from firmware_sim.servers.pty_server import PtyServer
from hil.link.transports.can_bus import CanTransport
from protocol.frame import Framer
from protocol.messages import Heartbeat

STEP_S = 0.004
"""Board time each read of the clock moves it on (the loop's own cost, in lockstep)."""
PERIOD_S = 0.1
"""The host's heartbeat period: ten times inside HOST_SILENCE_S."""
STALL_S = HOST_SILENCE_S + 0.5
QUIET_AFTER_S = 0.3
"""A silent host's silence after the stall: a few looks of the board's loop."""
SERVE_S = 2.5
"""Board time served: the stall, and a second of talk after it."""
READS_PER_PASS = 8
"""More than the clock reads of one pass of either loop: the positions walked cover a whole pass."""


class StallingClock:
    """A board's clock that, once attached to its host (:meth:`attach`), moves ``STEP_S`` at each read
    and ``STALL_S`` at its ``at``-th read (the server's process stopped there). The host's ``speak`` is
    called inside a read whenever the time crosses a multiple of ``PERIOD_S``: at the stall's read if
    ``talks_in_stall``. If not, the host is silent from two passes before the stall (its last bytes
    taken before it: bytes found waiting on waking cannot be told from bytes sent all through the
    stall, and a host is gone only when the board looked and did not hear it) until ``QUIET_AFTER_S``
    after it. Before it is attached (the board and server being built) it stands at 0."""

    def __init__(self, at: int, talks_in_stall: bool) -> None:
        self._speak: Callable[[], None] | None = None
        self._at = at
        self._talks_in_stall = talks_in_stall
        self._t = 0.0  # the r-th read before the stall reads r * STEP_S
        self._quiet = (
            (math.inf, -math.inf) if talks_in_stall else ((at - 2 * READS_PER_PASS) * STEP_S, math.inf)
        )
        self.reads = 0

    def attach(self, speak: Callable[[], None]) -> None:
        self._speak = speak

    def now(self) -> float:
        if self._speak is None:
            return self._t
        self.reads += 1
        before = self._t
        if self.reads == self._at:
            self._t += STALL_S
            if not self._talks_in_stall:
                self._quiet = (self._quiet[0], self._t + QUIET_AFTER_S)
        else:
            self._t += STEP_S
        crossed = math.floor(self._t / PERIOD_S) > math.floor(before / PERIOD_S)
        quiet = self._quiet[0] <= self._t <= self._quiet[1]
        if self.reads == 1 or (crossed and not quiet):
            self._speak()
        return self._t


@contextmanager
def can_served(at: int, talks_in_stall: bool) -> Iterator[BoardServer]:
    url = virtual_url(node=4)
    framer = Framer()
    with CanTransport(url) as host:
        clock = StallingClock(at, talks_in_stall)
        server = CanServer(Board(BoardConfig(n_units=1), clock), url)
        clock.attach(lambda: host.write(framer.encode(Heartbeat())[1]))  # a virtual bus: delivered at once
        try:
            yield server
        finally:
            server.close()


@contextmanager
def pty_served(at: int, talks_in_stall: bool) -> Iterator[BoardServer]:
    framer = Framer()
    clock = StallingClock(at, talks_in_stall)
    server = PtyServer(Board(BoardConfig(n_units=1), clock))
    slave = os.open(server.path, os.O_RDWR | os.O_NOCTTY)

    def speak() -> None:
        os.write(slave, framer.encode(Heartbeat())[1])
        # The pty passes bytes on asynchronously: they are waiting at the master before time moves on.
        assert server._master is not None
        readable, _, _ = select.select([server._master], [], [], 2.0)
        assert readable, "the pty did not pass the host's bytes on within 2 s"

    clock.attach(speak)
    try:
        yield server
    finally:
        os.close(slave)
        server.close()


SERVERS = {"can": can_served, "pty": pty_served}


def _served(transport: str, at: int, talks_in_stall: bool) -> BoardServer:
    with SERVERS[transport](at, talks_in_stall) as server:
        server.serve(SERVE_S)
        return server


def _check(server: BoardServer, talks_in_stall: bool) -> None:
    stats = server.stats
    if talks_in_stall:
        assert (stats.host_gone, stats.reconnects, stats.host_present) == (0, 0, True), stats
    else:
        assert (stats.host_gone, stats.reconnects, stats.host_present) == (1, 1, True), stats


FIRST_AT = 40
"""A read well after the host's first bytes (the board has heard it: present)."""


@pytest.mark.parametrize("transport", sorted(SERVERS))
@pytest.mark.parametrize("offset", range(READS_PER_PASS))
def test_a_stall_at_each_point_of_a_pass_leaves_a_talking_host_present(transport: str, offset: int):
    _check(_served(transport, FIRST_AT + offset, True), True)


@pytest.mark.parametrize("transport", sorted(SERVERS))
@settings(max_examples=25, deadline=None)
@given(at=st.integers(FIRST_AT, 120), talks_in_stall=st.booleans())
def test_a_stall_at_a_drawn_read_is_silence_only_if_the_host_was_silent(
    transport: str, at: int, talks_in_stall: bool
):
    _check(_served(transport, at, talks_in_stall), talks_in_stall)
