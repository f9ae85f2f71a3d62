"""The board client: a :class:`~hil.link.board.session.Session` on a transport and a clock.

Two ways to drive the one core:

* **Caller's loop** (lockstep, or a real-time loop that owns its timing): call :meth:`BoardClient.service`
  every step. It reads what has arrived (never waiting), feeds the session, writes what is due
  (retries, heartbeats, held setpoints) and returns the new events. No threads: a lockstep run through the
  in-process emulator is deterministic.
* **Real time with a reader thread** (:meth:`BoardClient.start`): the thread waits on the transport,
  feeds the session and writes what is due; the caller sends setpoints and commands from its own thread
  and takes events with :meth:`BoardClient.drain_events` (or the ``on_event`` callback, called from the
  reader thread). An error in the reader thread is stored and raised by the caller's next call — never
  swallowed.

Blocking calls (:meth:`connect`, :meth:`arm`, :meth:`disarm`, :meth:`set_mode`, :meth:`wait`, the
calibration transfers) work in both: with a reader thread they wait for it; without one they drive the
session themselves, waiting in the transport's read on a real clock, and on a ``LockstepClock``
*advancing the clock* to the next thing due (the emulated board's next wake-up, a retry, a heartbeat), so
time passes during ``arm()`` as it would on a bench. A lockstep loop that must step its world while a
command is in flight uses :meth:`command` (a handle) and keeps calling :meth:`service` instead.

Link trouble is handled, not raised: a transport error (port vanished, bus down) or a board that stops
answering the handshake closes the transport and reopens it after a bounded, doubling back-off, then
handshakes again and reports :class:`ConnectedEvent` (it re-arms only if ``rearm_on_reconnect`` asks).
A reconnect that reaches another board (another identity or unit count: a pty name reused by another
process after the board's was killed, a board swapped on the port) or an incompatible one is refused —
never commanded — and counted (``boards_refused``); the client closes the port and keeps looking for its
own board within the give-up bound. A port found busy on reconnection (:class:`PortBusy`: another host
holds its lock, so the path now leads to a board someone else drives — a reused pty number again, with
a board whose identity may match ours) is refused the same way before a byte is sent: counted in
``boards_refused``, logged once per run of refusals, retried. What is raised: :class:`HandshakeError`
(an incompatible board at connect), :class:`PortBusy` (another host holds the port at connect),
:class:`LinkTimeout` (no board answered the first handshake), :class:`LinkError` (reconnection given
up — its message carries the last refusal — or the client is closed), :class:`CommandFailed` (a command
NACKed or never answered), :class:`BoardReset` (a setpoint after the armed board reset; see
:mod:`hil.link.board.session`).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import threading
from collections import deque
from collections.abc import Callable
from types import TracebackType
from typing import Any

from hil.link.transports import InProcessBoard, Transport, create_transport
from hil.threads import ThreadError
from hil.timing.clock import Clock, LockstepClock, WallClock
from protocol.calibration import UnitCalibration
from protocol.errors import ConfigError, HandshakeError, HilError, LinkError, LinkTimeout, PortBusy
from protocol.messages import (
    ActuatorSetpoint,
    Arm,
    BoardState,
    ControlMode,
    Disarm,
    RawPulses,
    SetMode,
    Telemetry,
)
from protocol.reliable import Command

from .config import ClientConfig
from .events import BoardInfo, Event
from .session import Phase, Session
from .stats import LinkStats

logger = logging.getLogger(__name__)

_MIN_STEP_S = 1e-6  # a lockstep wait always moves the clock at least this far


class BoardClient:
    """Talk to one board over ``port`` (a transport URL or an unopened :class:`Transport`).

    ``clock``: the time base of everything timed (default: the emulator's if ``port`` is an
    in-process board (:class:`~hil.link.transports.InProcessBoard`) built with one, else a WallClock). A
    ``LockstepClock`` needs an in-process board (``emu://``): any other board runs in real time.
    ``on_event`` is called with every
    :mod:`event <hil.link.board.events>` as well as queuing it.
    """

    def __init__(
        self,
        port: str | Transport,
        clock: Clock | None = None,
        config: ClientConfig | None = None,
        on_event: Callable[[Event], None] | None = None,
    ) -> None:
        transport = create_transport(port) if isinstance(port, str) else port
        if isinstance(transport, InProcessBoard):
            clock = clock if clock is not None else transport.clock
            clock = clock if clock is not None else WallClock()
            transport.bind_clock(clock)
        self.clock: Clock = clock if clock is not None else WallClock()
        self.lockstep = isinstance(self.clock, LockstepClock)
        if self.lockstep and not isinstance(transport, InProcessBoard):
            raise ConfigError(
                f"{transport.url} runs in real time; a LockstepClock needs the in-process emulator (emu://)",
                "BoardClient.clock",
            )
        self.transport = transport
        self.config = config if config is not None else ClientConfig()
        self.session = Session(self.config)
        self.on_event = on_event
        self._events: deque[Event] = deque(maxlen=self.config.event_queue)
        self._cond = threading.Condition(threading.RLock())
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        # The reader thread's error, or a fatal one of the session met in the caller's pump: raised by
        # every later call; the session's own HilError (an incompatible board) as it is, anything else
        # as a LinkError naming the transport.
        self._thread_error = ThreadError(
            lambda: f"{self.transport.url}: the reader thread failed", as_is=HilError
        )
        self._closed = False
        self._connected = False  # a session was established once: from then on, losses are reconnected
        self._reconnect_at: float | None = None
        self._attempts = 0
        self._lost_at: float | None = None
        self._last_error = ""
        self._busy_logged = False  # the current run of "port busy" refusals was logged
        self._write_failure: LinkError | None = None  # a write failed in the caller's thread
        self._read_end: float | None = None  # when the last read of the transport returned (or it opened)
        self._port_absent = False  # the link is down and the port was seen gone since (Transport.present)
        self._open_due = False  # a reconnection try is due: the pump opens the port outside the lock
        self._close_due = False  # the link was lost: the pump closes the port outside the lock

    # ================================================================== session
    def connect(self, timeout: float | None = None) -> BoardInfo:
        """Open the transport and handshake (a no-op while a session is up). Raises
        :class:`TransportError` (cannot open), :class:`LinkTimeout` (no answer within the handshake's
        tries or ``timeout`` s) or :class:`HandshakeError` (incompatible board, naming both sides'
        version and schema hash); a failed first connect stops the reader thread and leaves the transport
        closed, ready to retry."""
        try:
            with self._cond:
                self._check()
                if self.session.phase is Phase.READY and self.session.info is not None:
                    return self.session.info
                if not self.transport.is_open:
                    self.transport.open()
                now = self.clock.now()
                self._read_end = now  # a port opened anew holds nothing older than this (as in _reopen)
                self._write(self.session.link_up(now), now)
            if not self._wait_until(lambda: self.session.phase is not Phase.HANDSHAKING, timeout):
                with self._cond:
                    instead = self.session.heard_instead() + self.transport.heard_instead()
                raise LinkTimeout(f"{self.transport.url}: no handshake within {timeout} s{instead}")
            with self._cond:
                self._check()
                info = self.session.info
                if self.session.phase is not Phase.READY or info is None:
                    failure = self.session.failure
                    raise (
                        self._told(failure)
                        if failure is not None
                        else LinkTimeout(
                            f"{self.transport.url}: the board did not answer{self.transport.heard_instead()}"
                        )
                    )
                self._connected = True
                return info
        except HilError:
            if not self._connected:  # leave nothing half-open: stop the reader, close, and allow a retry
                self.stop()
                with self._cond:
                    self._thread_error.clear()  # it is being raised to the caller right now
                    self.transport.close()
                    self.session.link_down(self.clock.now(), "connect failed", lost=False)
            raise

    def start(self) -> BoardClient:
        """Real-time mode: a reader thread feeds the session from now on (until :meth:`stop`)."""
        if self.lockstep:
            raise ConfigError("a lockstep client is driven by service(), not a reader thread", "start()")
        with self._cond:
            self._check()
            if self._thread is None:
                self._stop.clear()
                self._thread = threading.Thread(
                    target=self._reader, name=f"board-client {self.transport.url}", daemon=True
                )
                self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the reader thread (the caller drives the session again with :meth:`service`)."""
        self._stop.set()
        thread, self._thread = self._thread, None
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=5.0)

    def close(self) -> None:
        """Stop the reader thread and close the transport. Idempotent. The board is *not* disarmed
        here (call :meth:`disarm` first); its link watchdog makes it safe within its timeout."""
        self.stop()
        with self._cond:
            self._closed = True
            self.transport.close()
            self.session.link_down(self.clock.now(), "closed by the host", lost=False)
            self._dispatch()

    def __enter__(self) -> BoardClient:
        self.connect()
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    # ================================================================== driving
    def service(self, now: float | None = None) -> list[Event]:
        """One step of the caller's loop: take what arrived, send what is due; returns the new events.
        ``now`` defaults to the clock's time (in lockstep pass the clock's time or nothing). With the
        reader thread running it only raises the thread's error and returns the queued events."""
        if self._thread is None:
            self._pump(0.0, now)
        else:
            with self._cond:
                self._check()
        return self.drain_events()

    def drain_events(self) -> list[Event]:
        """Every event queued since the last drain, oldest first."""
        with self._cond:
            events = list(self._events)
            self._events.clear()
            return events

    def wait_for(self, predicate: Callable[[], object], timeout: float | None = None) -> bool:
        """Block until ``predicate()`` is truthy (True) or ``timeout`` s pass on the client's clock (False);
        the session is driven meanwhile (lockstep: the clock advances)."""
        return self._wait_until(predicate, timeout)

    # ================================================================== commands and setpoints
    def send_setpoint(self, setpoint: ActuatorSetpoint | RawPulses) -> None:
        """Send a setpoint (never acknowledged; newest wins; rate-limited to the board's frame rate ×2).

        Raises :class:`BoardReset` if the armed board reset (until :meth:`arm` or :meth:`disarm`),
        :class:`ProtocolError`/:class:`FieldRangeError` for one that does not fit the board. While the
        link is down it is dropped and counted (``stats().counters.setpoints_dropped``)."""
        with self._cond:
            self._check()
            now = self.clock.now()
            self._write(self.session.setpoint(setpoint, now), now)
            self._dispatch()

    def command(self, message: Any) -> Command:
        """Send a reliable command without waiting; the handle settles as answers arrive (during
        :meth:`service` or in the reader thread). Raises :class:`LinkError` without a session."""
        with self._cond:
            self._check()
            now = self.clock.now()
            cmd, data = self.session.command(message, now)
            self._write(data, now)
            self._dispatch()
            return cmd

    def wait(self, cmd: Command, timeout: float | None = None) -> Any:
        """Block until ``cmd`` settles; its answer, or :class:`CommandFailed` (NACKed, no answer after
        every retry, link lost). ``timeout`` (s): :class:`LinkTimeout` if it is still pending then."""
        if not self._wait_until(lambda: cmd.done, timeout):
            raise LinkTimeout(f"{type(cmd.message).__name__} still unanswered after {timeout} s")
        return cmd.result()

    def arm(self, timeout: float | None = None) -> None:
        """Arm (from DISARMED or FAILSAFE): setpoints drive the outputs from now on."""
        self.wait(self.command(Arm()), timeout)

    def disarm(self, timeout: float | None = None) -> None:
        """Disarm: rotors to the safe pulse, gimbals hold."""
        self.wait(self.command(Disarm()), timeout)

    def set_mode(self, mode: ControlMode, timeout: float | None = None) -> None:
        """How the board turns setpoints into pulses (only while DISARMED)."""
        self.wait(self.command(SetMode(mode=mode)), timeout)  # FieldRangeError for a mode not in ControlMode

    def upload_calibration(
        self, unit: int, calibration: UnitCalibration, timeout: float | None = None
    ) -> None:
        """Store ``calibration`` on the board for ``unit`` (DISARMED; every fragment acknowledged)."""
        with self._cond:
            fragments = self.session.upload_fragments(unit, calibration)
        for cmd in [self.command(f) for f in fragments]:
            self.wait(cmd, timeout)

    def download_calibration(self, unit: int, timeout: float | None = None) -> UnitCalibration:
        """The calibration the board holds for ``unit``. Raises :class:`CommandFailed` (refused: no
        calibration, busy), :class:`CalibrationError` (a set that does not reassemble or parse),
        :class:`LinkTimeout` (incomplete after ``timeout`` s, or no fragment from the board for
        ``config.download_idle_s``: it gave the transfer up — even without a ``timeout``)."""
        with self._cond:
            self._check()
            now = self.clock.now()
            download, data = self.session.start_download(unit, now)
            self._write(data, now)
            self._dispatch()
        if not self._wait_until(lambda: download.done, timeout):
            with self._cond:
                if not download.done:  # else it completed just now: its result is the caller's
                    # no longer tracked: its late fragments are refused, not taken into a download
                    # nobody reads (and held for the rest of the session)
                    self.session.cancel_download(download, f"incomplete after {timeout} s")
        return download.result()

    # ================================================================== state
    @property
    def info(self) -> BoardInfo | None:
        """The board's HelloReply (identity, units, frame rate), once connected."""
        return self.session.info

    @property
    def state(self) -> BoardState | None:
        """The board's latest known state."""
        return self.session.state

    @property
    def telemetry(self) -> Telemetry | None:
        """The latest Telemetry (the host time it was made: :attr:`telemetry_time`)."""
        return self.session.telemetry

    @property
    def telemetry_time(self) -> float | None:
        """The host time the latest Telemetry was made: its receive time while the client reads promptly;
        read after the client itself fell behind (a paused process or reader, a reopened port), what the
        board's clock says (:mod:`hil.link.board.made_at`): a backlog is not taken for live."""
        return self.session.telemetry_time

    def latest_telemetry(self) -> tuple[Telemetry | None, float | None]:
        """The latest Telemetry and the host time it was made (:attr:`telemetry_time`), as one pair read
        under the client's lock. Why: with the reader thread running, the two properties read one after
        the other could straddle a frame — the older message with the newer frame's time (about one read
        in 10 000 at 500 Hz; after a stall, the message from before it, ARMED with its rotors at speed,
        paired with the first new frame's time and shown live while that frame said FAILSAFE)."""
        with self._cond:
            return self.session.telemetry, self.session.telemetry_time

    @property
    def arm_acked_at(self) -> float | None:
        """The host time the board last acknowledged an Arm (None: none yet, or a Disarm sent since)."""
        return self.session.arm_acked_at

    @property
    def connected(self) -> bool:
        """A session is up right now (not handshaking, not reconnecting)."""
        return self.session.phase is Phase.READY

    def stats(self) -> LinkStats:
        """A snapshot of the link statistics."""
        with self._cond:
            s = self.session
            d = s.deframer.counters
            cmd, hello = s.commands.stats, s.hellos.stats
            tel = s.telemetry
            counters = getattr(self.transport, "counters", None)
            return LinkStats(
                bytes_in=self.transport.bytes_in,
                bytes_out=self.transport.bytes_out,
                frames_in=d.frames,
                bad_frames={reason.value: n for reason, n in d.bad.items()},
                resyncs=d.resyncs,
                seq_gaps=s.seq_gaps,  # the board's frames only: the host's echoes are no gaps
                duplicates=s.duplicates,
                commands_sent=cmd.sent + hello.sent,
                retries=cmd.retransmits + hello.retransmits,
                acked=cmd.acked + hello.acked,
                nacked=cmd.nacked,
                failed=cmd.failed + hello.failed,
                late_answers=cmd.late_answers + hello.late_answers,
                unmatched_answers=cmd.unmatched_answers + hello.unmatched_answers,
                superseded=cmd.superseded,
                rtt=s.rtt.summary(),
                counters=dataclasses.replace(s.counters),
                board_rx_frames=None if tel is None else tel.rx_frames,
                board_rx_bad=None if tel is None else tel.rx_bad,
                board_seq_gaps=None if tel is None else tel.seq_gaps,
                transport=dict(counters()) if callable(counters) else {},
            )

    # ================================================================== internals
    def _check(self) -> None:
        """Raise the stored error (from the reader thread or an earlier pump); refuse a closed client."""
        self._thread_error.check()
        if self._closed:
            raise LinkError(f"{self.transport.url}: the board client is closed")

    def _reader(self) -> None:
        try:
            while not self._stop.is_set():
                now = self.clock.now()
                self._pump(max(min(self._next_wake(now), now + self.config.max_block_s) - now, 0.0))
        except BaseException as exc:  # stored and raised in the caller's loop: never swallowed
            with self._cond:
                self._thread_error.store(exc)
                self._cond.notify_all()

    def _wait_until(self, predicate: Callable[[], object], timeout: float | None) -> bool:
        clock = self.clock
        end = math.inf if timeout is None else clock.now() + timeout
        if self._thread is not None:
            if threading.current_thread() is self._thread:
                raise RuntimeError(
                    "a blocking BoardClient call from its own reader thread (an on_event "
                    "callback) would wait for itself; use command() there"
                )
            with self._cond:
                while True:
                    self._check()
                    if predicate():
                        return True
                    remaining = end - clock.now()
                    if remaining <= 0:
                        return False
                    self._cond.wait(min(remaining, self.config.max_block_s))
        read_wait = 0.0
        while True:
            self._pump(read_wait)
            if predicate():
                return True
            now = clock.now()
            if now >= end:
                return False
            wake = min(end, self._next_wake(now))
            if self.lockstep:
                if wake == math.inf:  # nothing due ever, no bound: in lockstep nothing else moves time
                    return False
                clock.sleep_until(max(wake, now + _MIN_STEP_S))
            else:
                read_wait = max(min(wake, now + self.config.max_block_s) - now, 0.0)

    def _next_wake(self, now: float) -> float:
        """When the session, a reconnection or the emulated board next has something to do."""
        wake = self.session.next_deadline()
        if self._reconnect_at is not None:
            wake = min(wake, self._reconnect_at)
        if isinstance(self.transport, InProcessBoard) and self._port_open():
            wake = min(wake, self.transport.next_wake())
        return wake

    def _pump(self, read_timeout: float, now: float | None = None) -> None:
        """Read (waiting up to ``read_timeout`` s on a real clock), feed, write what is due, reconnect."""
        with self._cond:
            self._check()
        data = b""
        waiting_since = self._read_end  # what this read returns may have waited since then
        if self._port_open():
            try:
                data = self.transport.read(read_timeout)
                self._read_end = self.clock.now()
            except LinkError as exc:
                with self._cond:
                    self._lose_link(self.clock.now(), exc)
        elif read_timeout > 0:
            self.clock.sleep_until(self.clock.now() + read_timeout)  # link down: nothing to wait on
        with self._cond:
            try:
                now = self.clock.now() if now is None else now
                if self._write_failure is not None:
                    failure, self._write_failure = self._write_failure, None
                    self._lose_link(now, failure)
                out = self.session.feed(data, now, waiting_since) if data else b""
                self._write(out + self.session.poll(now), now)
                self._keep_link(now)
            except HilError as exc:  # fatal for the session (incompatible board, reconnection given up)
                if self._connected:
                    # raised again by every later call (before: connect() may be retried)
                    self._thread_error.store(exc)
                raise
            finally:
                self._dispatch()
                self._cond.notify_all()
        if self._close_due:
            self._close_lost_port()
        if self._open_due:
            self._reopen()

    def _port_open(self) -> bool:
        """Whether the transport is open and not lost: a port whose link was lost is closed by the pump,
        outside the lock (:meth:`_close_lost_port`), and is read and written no more meanwhile."""
        return self.transport.is_open and not self._close_due

    def _close_lost_port(self) -> None:
        """The port of a lost link closed outside the client's lock, as :meth:`_reopen` opens it: pyserial's
        ``socket://`` and ``rfc2217://`` sleep 0.3 s in their close ("give the server some time"; rfc2217
        joins its reader for up to 7 s first), and under the lock that held every caller's
        ``send_setpoint`` as long — the run took the loss of a TCP board for its own control tick's stall
        (``host_stall``). Only the pump closes or opens, so nothing else uses the transport meanwhile."""
        self.transport.close()
        with self._cond:
            self._close_due = False

    def _reopen(self) -> None:
        """A reconnection's try (:meth:`_keep_link` found one due), the port opened outside the client's
        lock: a connect that waits — a TCP board whose accept queue is full, pyserial's ``socket://``
        waiting up to 5 s, an ``rfc2217://`` negotiation, a slow CAN backend — held every caller's
        ``send_setpoint`` and the state's reads as long, and the run took its own control tick for the stall
        (``host_stall``) instead of the link's loss. Only the pump opens, so no other thread reads,
        writes or opens the transport meanwhile (it is closed: reads and writes skip it)."""
        self._open_due = False
        with self._cond:
            if self._closed:
                return
        failure: LinkError | None = None
        try:
            self.transport.open()
        except LinkError as exc:  # PortBusy among them
            failure = exc
        with self._cond:
            now = self.clock.now()
            s = self.session
            try:
                if self._closed:  # closed while it opened: nothing of it kept
                    if failure is None:
                        self.transport.close()
                    return
                if failure is None:
                    self._busy_logged = self._port_absent = False
                    self._reconnect_at = None
                    # What the new connection's first read returns waited since its opening, not since the
                    # last read before the loss: taken for a late read, the restarted board's first samples
                    # were dated by the board's clock from that read — seconds before it even restarted.
                    self._read_end = now
                    self._write(s.link_up(now), now)
                    return
                if isinstance(failure, PortBusy):
                    # Another host holds the port: whatever board is behind it is not ours to command (our
                    # own board would be held by nobody). Not fatal: the holder may let go, the path may be
                    # ours again.
                    s.counters.boards_refused += 1
                    if not self._busy_logged:
                        self._busy_logged = True
                        logger.warning("reconnection refused, not our board: %s; still looking", failure)
                self._last_error = str(failure)
                self._reconnect_at = now + self.config.reconnect_delay(self._attempts)
            finally:
                self._dispatch()
                self._cond.notify_all()

    def _write(self, data: bytes, now: float) -> None:
        if data and self._port_open() and self._write_failure is None:
            try:
                self.transport.write(data)
            except LinkError as exc:
                reader = self._thread
                if reader is not None and reader is not threading.current_thread():
                    self._write_failure = exc  # the reader thread, maybe inside read(), closes the port
                else:
                    self._lose_link(now, exc)

    def _lose_link(self, now: float, exc: BaseException) -> None:
        """The transport failed: before the first session that is the caller's error; after it, close,
        tell the session and schedule a reconnection."""
        if not self._connected:
            raise exc
        self._last_error = str(exc)
        self._close_due = True  # closed by the pump once it has let go of the lock (_close_lost_port)
        self.session.link_down(now, str(exc))
        if self._lost_at is None:
            self._lost_at, self._attempts = now, 0
        self._reconnect_at = now + self.config.reconnect_delay(self._attempts)

    def _told(self, failure: HilError) -> HilError:
        """A first handshake's ``LinkTimeout`` with what the transport heard instead appended (frames of
        another kind of CAN frame than this end's: the board has another ``fd`` option)."""
        heard = self.transport.heard_instead()
        if isinstance(failure, LinkTimeout) and heard and heard not in str(failure):
            told = LinkTimeout(f"{failure}{heard}")
            told.__cause__ = failure
            return told
        return failure

    def _keep_link(self, now: float) -> None:
        s = self.session
        if self._connected and self._reconnect_at is None and not self._port_open():
            # Closed behind the client's back between reads (by another thread or a backend), not by
            # _lose_link (which schedules the reconnection): a write to a closed port is skipped and
            # nothing is read, so without this the session would wait on it forever.
            self._lose_link(now, LinkError(f"{self.transport.url}: the port was closed under the client"))
        if s.phase is Phase.INCOMPATIBLE:
            assert isinstance(s.failure, HandshakeError)
            if not self._connected:
                raise s.failure  # the first board is the caller's to fix
            s.counters.boards_refused += 1  # not ours: never commanded; ours may come back on the port
            self._lose_link(now, s.failure)
            return
        if s.phase is Phase.DOWN and s.failure is not None and not self._connected:
            raise self._told(s.failure)  # the first handshake went unanswered
        if s.phase is Phase.READY:
            self._lost_at, self._attempts, self._busy_logged = None, 0, False
            return
        if s.phase is Phase.DOWN and self._port_open() and self._connected:
            self._lose_link(now, s.failure or LinkError("session lost"))  # the board stopped answering
        if self._reconnect_at is None or self._port_open():
            return
        if now < self._reconnect_at:
            self._watch_port(now)  # may bring the next try forward to now
            if now < self._reconnect_at:
                return
        assert self._lost_at is not None
        give_up = self.config.reconnect_give_up_s
        if give_up is not None and now - self._lost_at >= give_up:
            raise LinkError(
                f"{self.transport.url}: gave up reconnecting after {self._attempts} attempts over "
                f"{now - self._lost_at:.1f} s (last error: {self._last_error})"
            )
        self._attempts += 1
        self._open_due = True  # opened by the pump once it has let go of the lock (_reopen)

    def _watch_port(self, now: float) -> None:
        """While the link is down: a port seen gone that is there again is tried at once (its board
        restarted, its cable back), not at the back-off's next step — up to ``reconnect_max_s`` later
        (a board back 0.8 s after a loss waited until 1.55 s)."""
        present = self.transport.present()
        if present is False:
            self._port_absent = True
        elif present and self._port_absent:
            self._port_absent = False
            self._reconnect_at = now

    def _dispatch(self) -> None:
        for event in self.session.take_events():
            if len(self._events) == self._events.maxlen:
                self.session.counters.events_dropped += 1
            self._events.append(event)
            if self.on_event is not None:
                self.on_event(event)
