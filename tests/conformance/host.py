"""A minimal protocol host for tests: frames out, frames in, reliable commands with retries.

Deliberately independent of ``hil``'s board client (so the board and the client are each checked against
the protocol, not against each other). Two byte pipes: a real serial port (pyserial on a pty) with wall-time
timeouts, and an in-process lockstep board where every timeout is board time.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import serial

from protocol.frame import Deframer, Frame, Framer
from protocol.messages import SCHEMA_HASH, Ack, Heartbeat, Hello, HelloReply, Nack


class Host:
    """Speaks the protocol over ``_write``/``_read``; ``received`` keeps every decoded message in order.

    ``keepalive`` (a message factory) is sent every ``keepalive_period`` seconds of host time while the
    host waits, so the board's link watchdog stays fed (None: the host goes quiet)."""

    def __init__(self) -> None:
        self.framer = Framer()
        self.deframer = Deframer()
        self.received: list[Any] = []
        self.keepalive: Callable[[], Any] | None = None
        self.keepalive_period = 0.05
        self._next_keepalive = 0.0

    # ---------------------------------------------------------------- pipe (subclasses)
    def _write(self, data: bytes) -> None:
        raise NotImplementedError

    def _read(self, timeout: float) -> bytes:
        raise NotImplementedError

    def now(self) -> float:
        raise NotImplementedError

    # ---------------------------------------------------------------- messages
    def send(self, message: Any, seq: int | None = None) -> int:
        seq, data = self.framer.encode(message, seq=seq)
        self._write(data)
        return seq

    def send_raw(self, data: bytes) -> None:
        self._write(data)

    def poll(self, timeout: float = 0.0) -> list[Any]:
        """Messages that arrive within ``timeout`` seconds (at least one read)."""
        end = self.now() + timeout
        out: list[Any] = []
        while True:
            self._maybe_keepalive()
            remaining = end - self.now()
            step = min(max(remaining, 0.0), self.keepalive_period if self.keepalive else remaining)
            for event in self.deframer.feed(self._read(max(step, 0.0))):
                if isinstance(event, Frame):
                    out.append(event.message)
            if self.now() >= end:
                break
        self.received.extend(out)
        return out

    def wait_for(self, predicate: Callable[[Any], bool], timeout: float, what: str = "a message") -> Any:
        """The first message arriving from now on for which ``predicate`` holds (AssertionError: none)."""
        end = self.now() + timeout
        while self.now() < end:
            for msg in self.poll(min(0.02, max(end - self.now(), 0.0))):
                if predicate(msg):
                    return msg
        raise AssertionError(f"no {what} within {timeout} s")

    def wait_type(self, cls: type, timeout: float, where: Callable[[Any], bool] = lambda m: True) -> Any:
        return self.wait_for(lambda m: isinstance(m, cls) and where(m), timeout, cls.__name__)

    def request(self, message: Any, timeout: float = 0.1, tries: int = 20) -> Ack | Nack:
        """A reliable command: retried with the same sequence number until its Ack/Nack arrives."""
        seq = self.send(message)
        for attempt in range(tries):
            if attempt:
                self.send(message, seq=seq)
            end = self.now() + timeout
            while self.now() < end:
                for msg in self.poll(min(0.01, max(end - self.now(), 0.0))):
                    if isinstance(msg, (Ack, Nack)) and msg.msg_id == message.MSG_ID and msg.seq == seq:
                        return msg
        raise AssertionError(f"{type(message).__name__} not answered after {tries} tries")

    def handshake(self, timeout: float = 0.1, tries: int = 20, schema_hash: int = SCHEMA_HASH) -> HelloReply:
        hello = Hello(schema_hash=schema_hash, manufacturer="tests", model="conformance", serial="T1")
        for _ in range(tries):
            self.send(hello)
            try:
                reply: HelloReply = self.wait_type(HelloReply, timeout)
                return reply
            except AssertionError:
                continue
        raise AssertionError(f"no HelloReply after {tries} tries")

    def _maybe_keepalive(self) -> None:
        if self.keepalive is None:
            return
        t = self.now()
        if t >= self._next_keepalive:
            self._next_keepalive = t + self.keepalive_period
            self.send(self.keepalive())


def heartbeat() -> Heartbeat:
    return Heartbeat(time_ms=0, state=0)


class SerialHost(Host):
    """Host on a real serial port (a pty path) through pyserial; timeouts are wall time."""

    def __init__(self, port: str) -> None:
        super().__init__()
        self.port_name = port
        self.port = serial.Serial(port, baudrate=115200, timeout=0.01, write_timeout=2.0)

    def _write(self, data: bytes) -> None:
        self.port.write(data)

    def _read(self, timeout: float) -> bytes:
        self.port.timeout = timeout
        first = self.port.read(1)
        if not first:
            return b""
        waiting = self.port.in_waiting
        return first + self.port.read(waiting) if waiting else first

    def now(self) -> float:
        return time.monotonic()

    def reopen(self) -> None:
        """Close and reopen the port (a host reconnecting); the deframer starts afresh."""
        self.port.close()
        self.port = serial.Serial(self.port_name, baudrate=115200, timeout=0.01, write_timeout=2.0)
        self.deframer.reset()

    def close(self) -> None:
        self.port.close()


class LockstepHost(Host):
    """Host wired straight to a sans-IO board; every timeout is board time, advanced in lockstep."""

    def __init__(self, board: Any, clock: Any, max_step: float = 0.001) -> None:
        super().__init__()
        self.board = board
        self.clock = clock
        self.max_step = max_step

    def _write(self, data: bytes) -> None:
        self.board.feed(data)

    def _read(self, timeout: float) -> bytes:
        board, clock = self.board, self.clock
        end = clock.now() + timeout
        board.step()
        out = board.take_output()
        while not out and clock.now() < end:
            nxt = min(board.next_deadline(), end, clock.now() + self.max_step)
            clock.set(max(nxt, clock.now()))
            board.step()
            out = board.take_output()
        return out

    def now(self) -> float:
        return self.clock.now()

    def run(self, duration: float) -> list[Any]:
        """Let ``duration`` seconds of board time pass (keepalives sent), returning what arrived."""
        return self.poll(duration)


def lockstep(
    config: Any = None, calibrations: Any = None, start: float = 0.0
) -> tuple[Any, Any, LockstepHost]:
    """A fresh sans-IO board on a LockstepClock with a host wired to it, run past its boot."""
    from firmware_sim.board import Board
    from hil.timing.clock import LockstepClock

    clock = LockstepClock(start)
    board = Board(config, clock, calibrations=calibrations)
    host = LockstepHost(board, clock)
    host.poll(board.config.boot_time_s + 0.001)
    return board, clock, host
