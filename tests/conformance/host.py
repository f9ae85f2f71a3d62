"""A minimal protocol host for tests: frames out, frames in, reliable commands with retries.

Deliberately independent of ``hil``'s board client and transports (so the board and the client are each
checked against the protocol, not against each other). Every timeout is board time. Byte pipes: a real
serial port (pyserial on a pty) to a board that runs on its own, its clock read from the target
(:class:`SerialHost`); the same to a lockstep target, which the host runs while it waits
(:class:`LockstepSerialHost`); a python-can bus to a lockstep board served on it, the frames cut and
reassembled by :mod:`protocol.can` (:class:`LockstepCanHost`); and an in-process lockstep board
(:class:`LockstepHost`). :func:`connect` picks the one a target needs.

Every host counts what it put on the link (``bytes_sent``, ``frames_sent``) and what reached it
(``bytes_received``; its deframer's counters), for the link statistics both sides must agree on.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Sequence
from typing import Any
from urllib.parse import parse_qsl, urlsplit

import can
import serial

from protocol.can import CanReassembler, CanSegmenter, Direction
from protocol.frame import Deframer, Frame, Framer
from protocol.messages import SCHEMA_HASH, Ack, Heartbeat, Hello, HelloReply, Nack, Telemetry

STALLED_S = 30.0
"""A host waiting on a board whose clock does not move for this long (wall time) gives up."""
STREAM_GAP_S = 0.2
"""The longest a streaming host may leave the board without a frame (:meth:`Host.stream`): four keepalive
periods, far inside the link timeout of the tests about it."""
PTY_WALL_S = 30.0
"""How long a lockstep host waits (wall time) for bytes the pty owes it: only bounds a broken pty."""


class Host:
    """Speaks the protocol over ``_write``/``_read``; ``received`` keeps every decoded message in order.

    ``keepalive`` (a message factory) is sent every ``keepalive_period`` seconds of host time while the
    host waits, so the board's link watchdog stays fed (None: the host goes quiet).

    ``sends`` holds, for every frame sent, the host's time just before and just after writing it: a
    host the machine did not run for a while shows as a gap there (:meth:`kept_up`)."""

    def __init__(self) -> None:
        self.framer = Framer()
        self.deframer = Deframer()
        self.received: list[Any] = []
        self.sends: list[tuple[float, float]] = []
        self.keepalive: Callable[[], Any] | None = None
        self.keepalive_period = 0.05
        self._next_keepalive = 0.0
        self.bytes_sent = 0
        self.frames_sent = 0  # whole frames (send); torn ones are not counted (send_torn)
        self.bytes_received = 0

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
        self.send_raw(data)
        self.frames_sent += 1
        return seq

    def send_raw(self, data: bytes) -> None:
        before = self.now()
        self._write(data)
        self.bytes_sent += len(data)
        self.sends.append((before, self.now()))

    def damage_seen(self) -> int:
        """Damaged frames that reached this host and were discarded: on a serial link the deframer's bad
        frames."""
        return self.deframer.counters.bad_total

    def send_torn(self, wire: bytes) -> None:
        """The first half of the wire frame ``wire``, as a host that dies while sending it leaves: on a
        serial link its first bytes."""
        self.send_raw(wire[: len(wire) // 2])

    def kept_up(
        self, since: int, within: float, start: float | None = None, end: float | None = None
    ) -> bool:
        """Whether, from send number ``since`` on, no two frames the host sent can have been ``within``
        seconds (host time: the board's) or more apart — nor the first from ``start``, nor the last from
        ``end``, when given (times at which the host was running). A real-time board's link watchdog
        trips, rightly, when a loaded machine leaves the host unscheduled that long; a test about
        something else makes such an attempt again rather than blame the board."""
        stamps = ([] if start is None else [(start, start)]) + self.sends[since:]
        stamps += [] if end is None else [(end, end)]
        pairs = zip(stamps, stamps[1:], strict=False)
        return all(after - before < within for (before, _), (_, after) in pairs)

    def stream(self, seconds: float, within: float = STREAM_GAP_S, tries: int = 20) -> list[Any]:
        """Wait ``seconds`` with the keepalive going out (:meth:`poll`), and again until the host kept it
        going out at least every ``within`` seconds for that long: what a test means by "stream setpoints
        for a while", which a loaded machine may not have let a host on a real-time board do the first
        time (a lockstep host always does). What arrived meanwhile."""
        out: list[Any] = []
        for _ in range(tries):
            start, since = self.now(), len(self.sends)
            out += self.poll(seconds)
            if self.kept_up(since, within, start, self.now()):
                return out
        raise AssertionError(
            f"the host could not stream for {seconds} s in {tries} attempts (a busy machine)"
        )

    def first_after(self, message: Any, cls: type, timeout: float = 1.0) -> Any:
        """The first ``cls`` message received after ``message`` (one of :attr:`received`), waiting for it
        if it has not arrived yet: what the board sent after it, whenever the host got to read it."""
        index = next(i for i, m in enumerate(self.received) if m is message)
        got = next((m for m in self.received[index + 1 :] if isinstance(m, cls)), None)
        return got if got is not None else self.wait_type(cls, timeout)

    def poll(self, timeout: float = 0.0) -> list[Any]:
        """Messages that arrive within ``timeout`` seconds (at least one read)."""
        end = self.now() + timeout
        out: list[Any] = []
        moved = (self.now(), time.monotonic())  # the host's clock, and when it last moved (wall)
        while True:
            now = self.now()
            if now > moved[0]:
                moved = (now, time.monotonic())
            elif time.monotonic() - moved[1] > STALLED_S:
                raise AssertionError(f"the board's clock stood still at {now:.3f} s for {STALLED_S} s")
            self._maybe_keepalive()
            remaining = end - self.now()
            step = min(max(remaining, 0.0), self.keepalive_period if self.keepalive else remaining)
            data = self._read(max(step, 0.0))
            self.bytes_received += len(data)
            for event in self.deframer.feed(data):
                if isinstance(event, Frame):
                    out.append(event.message)
            if self.now() >= end:
                break
        self.received.extend(out)
        return out

    def wait_for(self, predicate: Callable[[Any], bool], timeout: float, what: str = "a message") -> Any:
        """The first message arriving from now on for which ``predicate`` holds (AssertionError: none)."""
        start = len(self.received)
        end = self.now() + timeout
        while self.now() < end:
            for msg in self.poll(min(0.02, max(end - self.now(), 0.0))):
                if predicate(msg):
                    return msg
        got = self.received[start:]
        raise AssertionError(f"no {what} within {timeout} s; {len(got)} other messages, the last: {got[-3:]}")

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
    """Host on a real serial port (a pty path) through pyserial. Its timeouts run on ``clock`` (the
    target's ``now``: board time, which may run slower than the wall clock on a loaded machine), or on
    the wall clock without one."""

    def __init__(self, port: str, clock: Callable[[], float] = time.monotonic) -> None:
        super().__init__()
        self.port_name = port
        self.clock = clock
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
        return self.clock()

    def reopen(self) -> None:
        """Close and reopen the port (a host reconnecting); the deframer starts afresh."""
        self.port.close()
        self.port = serial.Serial(self.port_name, baudrate=115200, timeout=0.01, write_timeout=2.0)
        self.deframer.reset()

    def close(self) -> None:
        self.port.close()


class LockstepSerialHost(SerialHost):
    """Host on a lockstep target's real pty (:class:`conformance.targets.FirmwareSimTarget`): its clock
    is the board's, and the board runs only while the host waits. Every byte the host writes reaches the
    board before the board's clock moves on, and every byte the board puts out is read before the host
    looks at the clock again: what the board does, and when, is the same however busy the machine is."""

    def __init__(self, target: Any, max_step: float = 0.001) -> None:
        self.target = target
        self.max_step = max_step
        super().__init__(target.port, clock=target.now)
        self._base = target.bytes_out  # what the board put out before this host opened the port
        self._got = 0

    def _write(self, data: bytes) -> None:
        super()._write(data)
        self.target.host_wrote(len(data))

    def _read(self, timeout: float) -> bytes:
        target = self.target
        end = target.now() + timeout
        while True:
            target.take_in()
            if target.bytes_out > self._base + self._got:
                return self._collect()
            if target.now() >= end:
                return b""
            target.advance(min(target.next_deadline(), end, target.now() + self.max_step))

    def _collect(self) -> bytes:
        """Every byte the board has put out so far (the pty passes them on asynchronously)."""
        want = self.target.bytes_out - self._base - self._got
        self.port.timeout = PTY_WALL_S
        data = self.port.read(want) if want > 0 else b""
        if len(data) < want:
            raise AssertionError(f"the pty passed on {len(data)} of the {want} bytes the board put out")
        waiting = self.port.in_waiting  # bytes left over from before this host opened the port, if any
        data += self.port.read(waiting) if waiting else b""
        self._got += len(data)
        return data

    def reopen(self) -> None:
        self._collect()  # what was on its way is gone with the old connection, not left for the new one
        super().reopen()
        self._base, self._got = self.target.bytes_out, 0

    def close(self) -> None:
        with contextlib.suppress(AssertionError, serial.SerialException):
            self._collect()
        super().close()


def quiet_on_arrival(received: Sequence[Any]) -> float:
    """The longest the board went, by its own telemetry, with no frame at all arriving — valid or damaged
    (``rx_frames + rx_bad`` standing still) — since traffic first reached it in ``received`` (s)."""
    longest, since, count = 0.0, None, None
    for m in received:
        if not isinstance(m, Telemetry):
            continue
        total, t = m.rx_frames + m.rx_bad, m.time_ms / 1000
        if count is not None and total > count:
            since = t
        elif count is not None and total < count:
            since = None  # the counters started again (a reset)
        elif since is not None:
            longest = max(longest, t - since)
        count = total
    return longest


def retry_if_starved(
    host: Host, attempt: Callable[[], Any], within: float, tries: int = 10, board: bool = False
) -> Any:
    """``attempt()``, made again when it failed (an AssertionError) while the host was not kept up: two
    frames it sent ``within`` seconds or more apart (:meth:`Host.kept_up`), a machine too busy to run it
    — or, with ``board``, the board going that long with nothing arriving (:func:`quiet_on_arrival`: a
    machine too busy to pass the host's bytes on to a real-time board). A failure while the host kept up
    is raised at once; a lockstep host always keeps up."""
    for _ in range(tries):
        sends, received = len(host.sends), len(host.received)
        try:
            return attempt()
        except AssertionError:
            starved = not host.kept_up(sends, within)
            if board:
                starved = starved or quiet_on_arrival(host.received[received:]) >= within
            if not starved:
                raise
    raise AssertionError(f"the host was left unscheduled for {within} s or more in all {tries} attempts")


class LockstepCanHost(Host):
    """Host on a lockstep target's CAN bus (:class:`conformance.targets.FirmwareSimCanTarget`: ``port``
    a ``can://<interface>/<channel>?node=N&fd=0|1[&port=P]`` URL). Frames are cut into segments and
    reassembled by :mod:`protocol.can` on python-can messages. Lockstep as over the pty: every segment
    the host sent reaches the board before its clock moves on (:meth:`target.host_sent`), and every
    segment the board sent is read before the host looks at the clock again."""

    def __init__(self, target: Any, max_step: float = 0.001) -> None:
        super().__init__()
        self.target = target
        self.max_step = max_step
        parts = urlsplit(target.port)
        options = dict(parse_qsl(parts.query))
        self.interface, self.channel = parts.netloc, parts.path[1:]
        self.node, self.fd = int(options.get("node", "0")), options.get("fd", "0") == "1"
        self._bus_options = {"port": int(options["port"])} if "port" in options else {}
        self.bus = self._open()
        self._segmenter = CanSegmenter(self.node, Direction.TO_BOARD, self.fd)
        self._reassembler = CanReassembler(self.node, Direction.TO_HOST)
        self._pending = bytearray()
        self._base = target.segments_out()  # what the board put on the bus before this host was on it
        self.segments_sent = 0
        self._closed = False

    def _open(self) -> can.BusABC:
        return can.Bus(interface=self.interface, channel=self.channel, fd=self.fd, **self._bus_options)

    def now(self) -> float:
        return float(self.target.now())

    def _send_segments(self, frames: Sequence[Any]) -> None:
        for f in frames:
            message = can.Message(
                arbitration_id=f.arbitration_id, data=f.data, is_fd=f.is_fd, is_extended_id=False
            )
            self.bus.send(message)
        self.segments_sent += len(frames)
        self.target.host_sent(len(frames))

    def _write(self, data: bytes) -> None:
        pending = self._pending
        pending += data
        while (end := pending.find(0)) >= 0:
            wire = bytes(pending[: end + 1])
            del pending[: end + 1]
            if len(wire) > 1:
                self._send_segments(self._segmenter.segment(wire))

    def send_torn(self, wire: bytes) -> None:
        """The first half of ``wire``'s segments (at least one, never all): a host gone mid-frame. A frame
        of one segment cannot be torn on a bus (it arrives whole or not at all)."""
        segments = self._segmenter.segment(wire)
        assert len(segments) >= 2, "a frame of one CAN segment cannot be torn: take a longer one"
        before = self.now()
        self._send_segments(segments[: len(segments) // 2])
        self.sends.append((before, self.now()))

    def damage_seen(self) -> int:
        """Damaged frames that reached this host: the deframer's bad frames, and those the reassembly
        already threw out — a frame whose bytes were damaged before they were cut into segments fails
        its CRC there (``spliced``), one that lost its delimiter never completes (``incomplete``)."""
        stats = self._reassembler.stats
        return super().damage_seen() + stats.spliced + stats.incomplete + stats.malformed

    def _received(self) -> int:
        stats = self._reassembler.stats
        return stats.segments + stats.malformed

    def _read(self, timeout: float) -> bytes:
        target = self.target
        end = target.now() + timeout
        while True:
            target.take_in()
            if target.segments_out() > self._base + self._received():
                return self._collect()
            if target.now() >= end:
                return b""
            target.advance(min(target.next_deadline(), end, target.now() + self.max_step))

    def _collect(self) -> bytes:
        """The frames of every segment the board has put on the bus so far (a bus passes them on
        asynchronously: waits for them, wall time only to bound a broken bus)."""
        want = self.target.segments_out() - self._base
        out = bytearray()
        deadline = time.monotonic() + PTY_WALL_S
        while self._received() < want:
            msg = self.bus.recv(max(deadline - time.monotonic(), 0.0))
            if msg is None:
                got = self._received()
                raise AssertionError(f"the bus passed on {got} of the {want} segments the board sent")
            out += self._reassembler.feed_message(msg)
        return bytes(out)

    def reopen(self) -> None:
        """Leave the bus and join it again (a host restarting): a new segmenter and reassembler."""
        with contextlib.suppress(AssertionError):
            self._collect()
        self.bus.shutdown()
        self.bus = self._open()
        self._segmenter = CanSegmenter(self.node, Direction.TO_BOARD, self.fd)
        self._reassembler = CanReassembler(self.node, Direction.TO_HOST)
        self._pending.clear()
        self._base = self.target.segments_out()
        self.deframer.reset()

    def close(self) -> None:
        if self._closed:
            return
        with contextlib.suppress(AssertionError):
            self._collect()
        self.bus.shutdown()
        self._closed = True


def connect(target: Any) -> Host:
    """A host on ``target``'s port, its timeouts on the board's clock: a lockstep target is run by the
    host while it waits, a real-time one runs on its own; a ``can://`` port is a CAN bus."""
    if str(target.port).startswith("can://"):
        return LockstepCanHost(target)
    if getattr(target, "lockstep", False):
        return LockstepSerialHost(target)
    return SerialHost(target.port, clock=target.now)


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
