"""The board client's core, sans-IO: bytes in, bytes out, events; every call takes ``now``.

:class:`Session` is the host's end of one board session — handshake, reliable commands, setpoints,
heartbeats, telemetry, reset detection, calibration transfers — with no transport, thread or clock inside
(like :mod:`protocol.reliable`, which it builds on). ``BoardClient`` drives it from a reader thread or from
the caller's loop; a test can drive it directly. Every method that may send returns the wire bytes to
write, in order; :meth:`Session.take_events` hands over what happened.

Phases::

    DOWN ──link_up()──► HANDSHAKING ──HelloReply (compatible)──► READY
      ▲                     │  │                                   │
      └── link_down() ◄─────┘  └─ HelloReply (incompatible) ──► INCOMPATIBLE (failure = HandshakeError)
          or no HelloReply after every try (failure = LinkTimeout)

**Reset detection.** The board draws a new boot id at every boot (``HelloReply.boot_id``,
``Heartbeat.boot_id``; 0 from a board that does not say): the id changing between what the host last heard
and what it hears now — in any heartbeat, or in the answer to a reconnect's handshake — says the board
reset, however soon it restarted and however long it then ran. The circumstantial evidence stays for a
board that sends 0. The board's uptime (``Heartbeat.time_ms``, ``Telemetry.time_ms``) only grows while
it runs. It going backwards, or the board reporting BOOT in the middle of a session or after a lost link
came back, means it reset. So does, after a reconnect, a first uptime shorter than the board had certainly
run by the reconnect's Hello — its uptime when last heard of (its last sample, or 0 at its first answer)
and the host time since (``AGE_SLACK_S`` and a clock 1 % slow allowed for): a board killed moments after
the handshake, before any sample, and restarted seconds before the host found it again. (Without a boot
id, a board that restarted while the link was down within ``AGE_SLACK_S`` of when it was last heard of,
and has already run longer than before, is not caught: nothing else it sends tells it from the board that
was there.) A reset the answer to a handshake reveals (its boot id) is reported at once, with that
answer's cause, before anything else is sent to the new boot. Otherwise the cause is in the next
``HelloReply``: if one arrived since the last uptime sample (a reconnect handshake),
it is used; otherwise the session handshakes again (Hello → the board is DISARMED with a new session)
and reports :class:`BoardResetEvent` with the cause it answers. A reset while the host had the board
armed also makes :meth:`Session.setpoint` raise :class:`BoardReset` until the caller arms (or disarms)
again: setpoints need an armed board, and the host never re-arms on its own. A non-power-on reset cause
seen at the first handshake is reported too (``during_session=False``).

**Setpoints** are never acknowledged: newest wins. At most one is sent per ``1 / max_setpoint_rate_hz``
(default: twice the board's pulse frame rate, so a loop at the frame rate is never held back by jitter);
one that comes sooner waits for its slot and is replaced by any newer one (counted as coalesced).

**Hostile but well-formed frames** are dropped, counted (:class:`SessionCounters`) and logged at most once
a second (``DROP_WARN_EVERY_S``, saying how many more since), never taken as the board's word: a
``Telemetry`` that does not fit the board that answered the handshake (another number of units or pulse
channels: the calibration tools index them by unit and channel), one identical to the telemetry already
held (a frame repeated by a stuck transmitter or replayed: taken, it would make old telemetry look live),
and a ``Telemetry`` or ``Heartbeat`` whose uptime or frame count leapt ahead of what the board could have
reached (:mod:`.leaps`: taken as the reference, the next honest sample looked like a reset). A
``HelloReply`` no Hello waits for and an ``Ack``/``Nack`` naming no command the host sent are counted by
the reliable senders and logged the same way (an answer to a command already settled only counted: a
lossy link's retries make those). The board's last frame repeated (its sequence number again, no
``RETRANSMIT``: a stuck transmitter, a far side repeating one greeting) is handled as before but not heard:
it never keeps a silent board looking alive. The board's
``Log`` frames are all reported as events, but logged at most ``BOARD_LOGS_PER_S`` a second (a board
flooding its log must not bury the host's own warnings); the rest are counted.

**The host's own frames coming back** (a port that echoes what is written: a loopback plug, TX joined to
RX, an echoing RS-485 adapter — :mod:`.echoes`) are told byte for byte from the board's, counted
(``echoes``) and dropped, warned of once per link; frames of kinds only a host sends that are not its own
(another host on the line) are counted too (``host_frames``). Neither is heard from the board: they never
keep a silent board looking alive (``last_heard``, silence), never pass for its Heartbeat (the host's
says BOOT and the host's clock: a spurious reset), its answers or its calibration fragments, and are left
out of the sequence numbers' gaps and repeats (:attr:`Session.seq_gaps`, :attr:`Session.duplicates`:
counted over the board's frames alone, the two ends numbering theirs each on its own). A handshake that no
board answered says whether the host's frames came back (:class:`LinkTimeout`).

Its configuration, :class:`ClientConfig`, is in :mod:`.config`; the calibration transfers' state
(:class:`Download`, fragments, reassembly) in :mod:`.transfers`. Both are re-exported here.
"""

from __future__ import annotations

import enum
import logging
import math
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass
from types import MethodType
from typing import Any

from protocol.calibration import UnitCalibration
from protocol.errors import (
    BoardReset,
    FieldRangeError,
    HandshakeError,
    HilError,
    LinkError,
    LinkTimeout,
    ProtocolError,
)
from protocol.frame import Deframer, Frame, Framer
from protocol.messages import (
    PROTOCOL_VERSION,
    Ack,
    ActuatorSetpoint,
    Arm,
    BoardState,
    CalibrationData,
    CalibrationRequest,
    Disarm,
    EscCalibrate,
    EscCalibrationStatus,
    Flags,
    Heartbeat,
    Hello,
    HelloReply,
    Log,
    Message,
    Nack,
    RawPulses,
    ResetCause,
    SetMode,
    Severity,
    Telemetry,
)
from protocol.reliable import Command, CommandState, ReliableSender

from ..throttle import Throttle
from .config import HOST_IDENTITY, ClientConfig
from .echoes import WrittenFrames
from .events import (
    BoardInfo,
    BoardResetEvent,
    CommandEvent,
    ConnectedEvent,
    EscCalibrationEvent,
    Event,
    LinkLostEvent,
    LogEvent,
    SilenceEvent,
    StateEvent,
    TelemetryEvent,
    printable,
)
from .leaps import CLOCK_RATE, LeapCheck, behind, went_back
from .made_at import MadeAt
from .stats import RttRing, SessionCounters
from .transfers import CalibrationTransfers, Download

__all__ = ["HOST_IDENTITY", "ClientConfig", "Download", "PendingReset", "Phase", "Session"]

logger = logging.getLogger(__name__)

_U32 = 1 << 32
OVERTAKEN_MS = 100
"""ms: how far a board's sample may be behind the newest sample of another kind and still be a frame that
was overtaken on the way, not a reset. On CAN frames go by priority: a Heartbeat (LINK) made 3 ms after a
Telemetry (STATUS, several segments) wins arbitration and comes first, and the Telemetry's uptime is then
behind the Heartbeat's — taken for a reset, 20 a second, each with a handshake that disarmed the board. A
kind's own frames come in order (one CAN id each, one serial stream), so its own count going back, or a
sample further behind, is still a reset — unless the board says its boot id (:meth:`Session._stale`)."""
SESSION_BOARD = "from the session's board"
"""Whose a HelloReply no Hello waits for is, said, when it is the session's board's own."""
STALE_REANCHOR = 3
"""Samples of the same boot behind the newest one heard, one after the other, after which the newest was
the absurd one (a sample ahead within the leaps' slack): the counts are anchored anew on the third."""
DROP_WARN_EVERY_S = 1.0
"""Host time (s) between two warnings about dropped board frames (the rest are counted, then summed)."""
AGE_SLACK_S = 0.5
"""s: how much younger than the time it had been known to run a board answering a reconnect may seem
(its first sample's latency, its clock's tick) before it is taken to have restarted meanwhile."""
RATE_BASELINE_S = 10.0
"""Host time (s) over which the board's samples must spread before its clock's rate against the host's is
taken from them (for :meth:`Session._younger_than_known`; shorter, the samples' latency would dominate)."""
SLOWEST_RATE = 0.5
"""The slowest a board's clock is taken to run against the host's, however slow its samples make it seem."""
BOARD_LOGS_PER_S = 20
"""The board's ``Log`` frames logged per second of host time; beyond, counted (``board_logs_unlogged``)."""
TWIN_RETURNS = 6
"""Boot ids already replaced heard again, within :data:`TWIN_WINDOW_S`, that say two boards answer as one
(:meth:`Session._twin_check`): twins interleave theirs many times a second; one board's never come back,
and an emulator restarted with its seed draws its earlier ids again only once per restart (seconds)."""
TWIN_WINDOW_S = 2.0
"""Host s within which :data:`TWIN_RETURNS` returns of replaced boot ids are two boards answering as one."""
TWIN_MEMORY = 8
"""The boot ids replaced that are remembered for :meth:`Session._twin_check` (the latest)."""
_SEQ_STEPS = 64
"""The board's last frames whose sequence steps are kept, for a new boot's first step to be taken back: a
board says its boot id in its first frames (a Heartbeat at boot), well within this."""
_LOG_LEVELS = {
    Severity.DEBUG: logging.DEBUG,
    Severity.INFO: logging.INFO,
    Severity.WARNING: logging.WARNING,
    Severity.ERROR: logging.ERROR,
    Severity.CRITICAL: logging.CRITICAL,
}


class Phase(enum.Enum):
    DOWN = "down"  # no link: not connected yet, or lost
    HANDSHAKING = "handshaking"  # Hello sent, waiting for HelloReply
    READY = "ready"  # a session is up: commands and setpoints go out
    INCOMPATIBLE = "incompatible"  # the board speaks another protocol version or schema: stop


@dataclass
class PendingReset:
    """A reset seen while the host had the board armed; setpoints raise :class:`BoardReset` until the
    caller arms or disarms. ``cause`` is None until the board's HelloReply tells it."""

    t: float
    evidence: str
    cause: ResetCause | None = None

    def error(self) -> BoardReset:
        cause = self.cause.name if self.cause is not None else "not known yet (handshaking again)"
        return BoardReset(cause, f"{self.evidence}; arm() again to continue")


class Session:
    """The host's end of a board session; see the module docstring. Not thread-safe: one driver."""

    def __init__(self, config: ClientConfig | None = None) -> None:
        self.config = config if config is not None else ClientConfig()
        self.framer = Framer()
        self.deframer = Deframer()
        self.commands = ReliableSender(
            self.framer,
            self.config.commands,
            on_settled=self._on_settled,
            on_late_answer=self._on_late_answer,
        )
        self.hellos = ReliableSender(self.framer, self.config.handshake, on_settled=self._on_hello_settled)
        self.counters = SessionCounters()
        self.rtt = RttRing(self.config.rtt_samples)
        self.phase = Phase.DOWN
        self.info: BoardInfo | None = None
        self.state: BoardState | None = None
        self.telemetry: Telemetry | None = None
        # host time the held telemetry was made: its receive time, or after the host fell behind on its
        # reads, the board's clock's word (.made_at)
        self.telemetry_time: float | None = None
        self.failure: HilError | None = None  # why the last handshake failed (HandshakeError, LinkTimeout)
        self.pending_reset: PendingReset | None = None
        self.armed = False  # the host armed the board (acknowledged) and has not disarmed it since
        # host time the board last acknowledged an Arm (None: none yet, or a Disarm sent since)
        self.arm_acked_at: float | None = None
        # host time of the board's last new frame (the host's own come back, and a frame repeated, left out)
        self.last_heard: float | None = None
        self.seq_gaps = 0  # board frames missing by their sequence numbers (the host's echoes left out)
        self.duplicates = 0  # board frames repeating the last one's sequence number
        self._board_seq: int | None = None  # the sequence number of the board's last frame on this link
        self._seq_steps: deque[tuple[int, int]] = deque(maxlen=_SEQ_STEPS)  # (seq, gap counted at it)
        self._written = WrittenFrames()  # what the host wrote lately: its echoes are told by it
        self._echoes_at_link_up = 0  # counters.echoes when the link came up
        self._host_frames_at_link_up = 0  # counters.host_frames when the link came up
        self._events: list[Event] = []
        self._out = bytearray()
        self._now = 0.0
        self._last_tx = -math.inf
        self._silent = False
        self._lost = False  # the link was lost since the last handshake (the next one is a reconnect)
        self._armed_at_loss = False  # the host had the board armed when the link was lost
        self._last_uptime: int | None = None  # the newest uptime (ms) of any kind of sample taken
        # each kind's (a Telemetry's, a Heartbeat's) last uptime (ms): a kind's frames come in order
        self._last_uptime_of: dict[type, int] = {}
        # this boot's uptime (ms) at its last sample taken, unwrapped past the u32 count's wraps (every
        # ~49.7 days): the clock the reset and latency checks go by (None: no sample of this boot yet)
        self._uptime_ms: int | None = None
        self._boot_id: int | None = None  # the board's boot id last heard (nonzero; None: none said yet)
        self._replaced_boots: deque[int] = deque(maxlen=TWIN_MEMORY)  # boot ids heard, then replaced
        self._boot_returns: deque[float] = deque(maxlen=TWIN_RETURNS)  # host s: a replaced one came back
        self.twins_said = False  # two boards answering as one were said (:meth:`_twin_check`)
        # (board uptime s, host time s): the board's current boot had run at least that long by then (its
        # first answer: 0 s; then each sample taken). None after a reset seen: the coming answer sets it.
        self._ran: tuple[float, float] | None = None
        self._clock_base: tuple[float, float] | None = None  # (uptime s, host s): this boot's first sample
        self._link_up_at = 0.0  # host time of the last link_up() (a reconnect's Hello went out after it)
        # host time of the first link_up() before any board answered: the host has had no board since
        self._reaching_since: float | None = None
        self._age_check_from: float | None = None  # set by a reconnect: its first sample's age is checked
        self._last_rx_frames: int | None = None  # the board's count of valid frames taken, since its boot
        self._reply_since_sample: HelloReply | None = None
        self._stale_in_a_row = 0  # samples of the same boot dropped one after the other as old (_stale)
        self._earlier_tries = 0  # the settled Hello's tries before the answered one, not answered yet
        self._reset_evidence: str | None = None
        self._boot_began: float | None = None  # host s: the reset held in _reset_evidence's new boot began
        self._setpoint_slot = -math.inf
        self._pending_setpoint: bytes | None = None  # one waiting for its slot, encoded (Framer.prepare)
        self._transfers = CalibrationTransfers()
        self._leaps = LeapCheck()
        self._made_at = MadeAt()
        self._telemetry_seq: int | None = None  # the sequence number of the telemetry held
        self._drop_warnings = Throttle(DROP_WARN_EVERY_S)
        self._reset_warnings = Throttle(DROP_WARN_EVERY_S)  # a reset storm: a line a second
        self._log_lines = Throttle(1.0, BOARD_LOGS_PER_S)  # board logs logged a second
        self._auto: dict[int, str] = {}  # id(Command) -> why the session sent it on its own
        self._receive: dict[type[Message], Callable[[Frame, float], None]] = {
            cls: MethodType(receive, self) for cls, receive in RECEIVE.items()
        }
        """:data:`RECEIVE` bound to this session: a frame's handler is one look-up by its message's type."""

    # ================================================================== link lifecycle
    def link_up(self, now: float) -> bytes:
        """The transport is (re)opened: start a handshake."""
        self._now = now
        self._link_up_at = now
        if self.info is None and self._reaching_since is None:
            self._reaching_since = now
        self.phase = Phase.HANDSHAKING
        self.failure = None
        self.deframer.reset()
        self._made_at.link_up()  # a pause before the loss is no lateness of the new connection's reads
        self._board_seq = None
        self._seq_steps.clear()
        self._echoes_at_link_up = self.counters.echoes
        self._host_frames_at_link_up = self.counters.host_frames
        self.last_heard = now
        self._silent = False
        self._hello(now)
        return self._take()

    def link_down(self, now: float, reason: str, lost: bool = True) -> None:
        """The transport failed (``lost``) or was closed on purpose: pending commands fail, partial input
        is forgotten."""
        self._now = now
        if self.phase is Phase.DOWN:
            return
        was_up = lost and self.info is not None
        self.phase = Phase.DOWN
        self._lost = self._lost or was_up
        self._armed_at_loss = self._armed_at_loss or (was_up and self.armed)
        self.counters.link_losses += was_up
        self.deframer.reset()
        self._board_seq = None
        self._seq_steps.clear()
        self._pending_setpoint = None
        why = f"link lost: {reason}"
        self.hellos.abandon(now, why)
        self.commands.abandon(now, why)
        self._transfers.abandon(why)
        if lost:
            self._emit(LinkLostEvent(now, reason))
            logger.warning("board link lost: %s", reason)

    # ================================================================== sending
    def command(self, message: Any, now: float) -> tuple[Command, bytes]:
        """Send a reliable command (Arm, Disarm, SetMode, CalibrationData, CalibrationRequest); returns its
        handle (settled later by the board's answer or by giving up) and the bytes to write."""
        self._require_session()
        self._now = now
        if isinstance(message, Disarm):
            self.armed = False  # the caller no longer wants the board armed, whatever the answer
            self.arm_acked_at = None
            self.pending_reset = None
        cmd, data = self.commands.send(message, now)
        self._put(data, now)
        return cmd, self._take()

    def setpoint(self, message: ActuatorSetpoint | RawPulses, now: float) -> bytes:
        """Send a setpoint now, or at its slot if the last one left less than a slot ago (newest wins).

        Raises :class:`BoardReset` after a reset of an armed board (until ``arm()``/``disarm()``),
        :class:`ProtocolError` for a setpoint that does not fit the board (unit/channel count),
        :class:`FieldRangeError` for an out-of-range or NaN value. Without a session (link down,
        handshaking) it is dropped and counted."""
        self._now = now
        if self.pending_reset is not None:
            raise self.pending_reset.error()
        body = self._check_setpoint(message)
        if self.phase is not Phase.READY:
            self.counters.setpoints_dropped += 1
            return b""
        if now >= self._setpoint_slot:
            self._send_setpoint(body, now)
        else:
            if self._pending_setpoint is not None:
                self.counters.setpoints_coalesced += 1
            self._pending_setpoint = body
        return self._take()

    def upload_fragments(self, unit: int, calibration: UnitCalibration) -> list[CalibrationData]:
        """The CalibrationData fragments that upload ``calibration`` to ``unit`` (send each with
        :meth:`command`; the board must be DISARMED)."""
        self._check_unit(unit)
        return self._transfers.upload_fragments(unit, calibration)

    def start_download(self, unit: int, now: float) -> tuple[Download, bytes]:
        """Ask the board for ``unit``'s stored calibration; the returned :class:`Download` completes as
        its fragments arrive (each acknowledged here)."""
        self._check_unit(unit)
        tid = self._transfers.next_transfer_id()
        cmd, data = self.command(CalibrationRequest(unit=unit, transfer_id=tid), now)
        return self._transfers.track(unit, tid, cmd), data

    def cancel_download(self, download: Download, why: str) -> None:
        """Stop waiting for ``download`` (its caller gave up: ``why``): it fails with :class:`LinkTimeout`
        and its late fragments are refused, not acknowledged (:meth:`CalibrationTransfers.cancel`)."""
        error = LinkTimeout(f"calibration download of unit {download.unit}: {why}")
        self._transfers.cancel(download, error)

    @property
    def downloads_running(self) -> int:
        """How many calibration downloads wait for fragments."""
        return self._transfers.running

    def poll(self, now: float) -> bytes:
        """Whatever is due at ``now``: retries, a held setpoint, a heartbeat; silence detection."""
        self._now = now
        self._put(self.hellos.poll(now), now)
        self._put(self.commands.poll(now), now)
        self._transfers.expire(now, self.config.download_idle_s)
        if self.phase is Phase.READY:
            if self._pending_setpoint is not None and now >= self._setpoint_slot:
                body, self._pending_setpoint = self._pending_setpoint, None
                self._send_setpoint(body, now)
            if now - self._last_tx >= self.config.heartbeat_period_s:
                self._send(Heartbeat(time_ms=round(now * 1000.0) % _U32, state=0), now)
                self.counters.heartbeats_sent += 1
            heard = self.last_heard
            if not self._silent and heard is not None and now - heard >= self.config.silence_after_s:
                self._silent = True
                self.counters.silences += 1
                self._emit(SilenceEvent(now, heard, ended=False))
                logger.warning("board silent for %.2f s", now - heard)
        return self._take()

    def next_deadline(self) -> float:
        """The earliest host time at which :meth:`poll` has work (inf: none)."""
        idle_since = self._transfers.idle_since()
        due = [
            self.hellos.next_deadline(),
            self.commands.next_deadline(),
            None if idle_since is None else idle_since + self.config.download_idle_s,
        ]
        if self.phase is Phase.READY:
            due.append(self._last_tx + self.config.heartbeat_period_s)
            if self._pending_setpoint is not None:
                due.append(self._setpoint_slot)
            if not self._silent and self.last_heard is not None:
                due.append(self.last_heard + self.config.silence_after_s)
        return min((d for d in due if d is not None), default=math.inf)

    # ================================================================== receiving
    def feed(self, data: bytes, now: float, waiting_since: float | None = None) -> bytes:
        """Bytes from the board, read at ``now``; returns the answers to write (Acks of calibration
        fragments, a Hello after a reset). ``waiting_since``: when the host's previous read ended (the
        bytes may have waited since; None: not known): a read long after it dates what it carries by the
        board's clock (:mod:`.made_at`)."""
        self._now = now
        self._made_at.read(now, waiting_since)
        for event in self.deframer.feed(data):
            if isinstance(event, Frame):
                self._on_frame(event, now)
        return self._take()

    @property
    def boot_id(self) -> int | None:
        """The board's boot id last heard (``HelloReply``/``Heartbeat.boot_id``); None until a board that
        says one has been heard."""
        return self._boot_id

    def take_events(self) -> list[Event]:
        events, self._events = self._events, []
        return events

    def _on_frame(self, frame: Frame, now: float) -> None:
        if self.phase is Phase.DOWN:
            return  # bytes still in flight from a link that is gone
        receive = self._receive[type(frame.message)]
        if type(frame.message) in HOST_WRITES and self._from_host(frame, now):
            return
        if self._count_board_seq(frame):
            receive(frame, now)  # taken as before (a repeated Telemetry is dropped there), but not heard
            return
        self.last_heard = now
        if self._silent:
            self._silent = False
            self._emit(SilenceEvent(now, now, ended=True))
        receive(frame, now)

    def _from_host(self, frame: Frame, now: float) -> bool:
        """Whether ``frame`` (of a kind the host writes) is a host's, not the board's: the host's own come
        back (counted in ``echoes``, warned of at the first on this link) or another host's (a kind only
        a host sends, not one this host wrote: ``host_frames``). Either is dropped, never heard from the
        board."""
        counters = self.counters
        if self._written.came_back(frame, now):
            counters.echoes += 1
            if counters.echoes == self._echoes_at_link_up + 1:
                logger.warning(
                    "the port echoes what the host writes (its %s came back): a loopback plug, TX joined to "
                    "RX or an echoing adapter; echoes are dropped and counted",
                    type(frame.message).__name__,
                )
            return True
        if type(frame.message) not in HOST_ONLY:
            return False  # a kind both ends send, not one of ours: the board's
        counters.host_frames += 1
        if counters.host_frames == self._host_frames_at_link_up + 1:
            logger.warning(
                "a %s arrived that this host did not write: another host is on the line (crossed "
                "wires?); such frames are dropped and counted",
                type(frame.message).__name__,
            )
        return True

    def _renumbered(self) -> None:
        """The frame just heard is of a new boot of the board, whose numbering began at 0 again: the step
        from the old boot's last frame to the new boot's first heard was no loss, and is taken back. The
        new boot's frames heard so far are the increasing run of sequence numbers that ends at this one
        (at most its number + 1 of them); a board reset added up to 255 "lost" frames to ``seq_gaps``."""
        heard = self._seq_steps
        if not heard:
            return
        k = len(heard) - 1
        newest = heard[k][0]
        while k > 0 and len(heard) - k <= newest and heard[k - 1][0] < heard[k][0]:
            k -= 1
        seq, gap = heard[k]
        self.seq_gaps -= gap
        heard[k] = (seq, 0)

    def _count_board_seq(self, frame: Frame) -> bool:
        """The board's sequence numbers, step by step: a jump of k > 1 is k - 1 frames lost, a repeat a
        duplicate. Counted here, not from the deframer's, which numbers every frame read — the host's
        echoes among them, each of those a false gap. Returns whether ``frame`` repeats the last one's
        number and is no retry: the same frame again (a transmitter stuck on it, a far side repeating one
        greeting to everything), which is no sign of a live board — it must not keep one looking alive."""
        seq = frame.seq
        last, self._board_seq = self._board_seq, seq
        step = 1 if last is None else (seq - last) & 0xFF
        gap = step - 1 if step > 1 else 0
        self._seq_steps.append((seq, gap))  # a new boot's first step is taken back (_renumbered)
        if step == 0:
            self.duplicates += 1
            return not frame.flags & Flags.RETRANSMIT
        self.seq_gaps += gap
        return False

    # ------------------------------------------------------------------ RECEIVE's handlers
    def _on_hello_reply_frame(self, frame: Frame, now: float) -> None:
        """Settles the handshake's Hello; one no Hello waits for is counted there (late or unmatched) and
        dropped here, logged saying whose it is — except the session's board's answers to the earlier
        tries of the Hello it settled, as many as those tries (:attr:`_earlier_tries`): a board that
        answered slowly (a USB accessory that opens after the host's first Hellos) answers each try, and
        every such run logged a warning for its own handshake."""
        if self.hellos.on_frame(frame, now) is not None:
            return
        reply: HelloReply = frame.message
        whose = self._whose(reply)
        if whose is None and self._earlier_tries > 0:
            self._earlier_tries -= 1  # counted late by the sender (an answer to a settled Hello's try)
            return
        self._drop(now, f"a HelloReply no Hello was waiting for, {whose or SESSION_BOARD}")

    def _whose(self, reply: HelloReply) -> str | None:
        """Whose an unasked-for HelloReply is, against the session's board: None for the session's own."""
        try:
            info = BoardInfo.from_reply(reply)
        except FieldRangeError as exc:  # it raised out of feed(), the session's frames after it unread
            return f"from a board whose identity no accessory has ({exc})"
        if (reply.protocol_version, reply.schema_hash) != (PROTOCOL_VERSION, self.config.schema_hash):
            return (
                f"from a board of protocol {reply.protocol_version}, schema hash {reply.schema_hash:#010x} "
                f"(not this host's): {info.describe()}"
            )
        held = self.info
        if held is not None and (held.identity, held.n_units) != (info.identity, info.n_units):
            return f"from another board than the session's: {info.describe()}"
        if held is not None and reply.boot_id and self._boot_id and reply.boot_id != self._boot_id:
            return f"from another boot of the session's board (boot id {reply.boot_id:#010x})"
        return None

    def _on_telemetry(self, frame: Frame, now: float) -> None:
        msg: Telemetry = frame.message
        misfit = self._telemetry_misfit(frame)
        if misfit is not None:
            self._drop(now, misfit)
            return
        made = self._board_clock(Telemetry, msg.time_ms, msg.state, now, msg.rx_frames)
        if made is None:
            return
        self.telemetry, self.telemetry_time, self._telemetry_seq = msg, made, frame.seq
        self._emit(TelemetryEvent(now, msg))

    def _telemetry_misfit(self, frame: Frame) -> str | None:
        """Why a Telemetry frame is not the board's word on now (counted here), or None to take it."""
        msg: Telemetry = frame.message
        info = self.info
        if info is not None and (len(msg.units), len(msg.pulses_us)) != (info.n_units, info.n_channels):
            self.counters.telemetry_misfits += 1
            return (
                f"Telemetry for {len(msg.units)} units and {len(msg.pulses_us)} pulse channels from a board "
                f"of {info.n_units} units and {info.n_channels} channels"
            )
        held_msg = self.telemetry
        # the uptime first: a cheap test that settles nearly every frame
        if held_msg is not None and msg.time_ms == held_msg.time_ms and msg == held_msg:
            self.counters.telemetry_repeats += 1
            held = self._telemetry_seq
            seq = "the same" if frame.seq == held else f"{frame.seq}, not {held}"
            return f"a Telemetry identical to the one held (board time {msg.time_ms} ms, seq {seq})"
        return None

    def _on_heartbeat(self, frame: Frame, now: float) -> None:
        msg: Heartbeat = frame.message
        try:
            state: BoardState | None = BoardState(msg.state)
        except ValueError:
            self.counters.unknown_board_states += 1
            state = None
        self._board_clock(Heartbeat, msg.time_ms, state, now, boot_id=msg.boot_id)

    def _on_log(self, frame: Frame, now: float) -> None:
        """Every Log is an event; at most :data:`BOARD_LOGS_PER_S` a second of them are logged, the first
        one logged after a flood saying how many were not."""
        msg: Log = frame.message
        self._emit(LogEvent(now, msg))
        more = self._log_lines.due(now)
        if more is None:
            self.counters.board_logs_unlogged += 1
            return
        since = f" ({more} board logs not logged before this one)" if more else ""
        logger.log(_LOG_LEVELS.get(msg.severity, logging.INFO), "board: %s%s", printable(msg.text), since)

    def _on_esc_calibration_status(self, frame: Frame, now: float) -> None:
        self._emit(EscCalibrationEvent(now, frame.message))

    def _on_answer(self, frame: Frame, now: float) -> None:
        """An Ack or Nack: settles the command it answers. A stray one is counted there: a late one (the
        answer to an earlier try, a board answering twice) quietly, one naming no command the host sent
        (a flood of them) also logged, at the drop warnings' rate."""
        stats = self.commands.stats
        unmatched = stats.unmatched_answers
        self.commands.on_frame(frame, now)
        if stats.unmatched_answers != unmatched:
            msg: Ack | Nack = frame.message
            self._drop(
                now,
                f"a {type(msg).__name__} naming no command the host sent (message id {msg.msg_id:#04x}, "
                f"seq {msg.seq})",
            )

    def _on_not_ours(self, frame: Frame, now: float) -> None:
        """A host-to-board message: never reached (:meth:`_from_host` counts and drops it first)."""
        raise AssertionError(f"a {type(frame.message).__name__} from the host reached its handler")

    def _board_clock(
        self,
        kind: type,
        uptime_ms: int,
        state: BoardState | None,
        now: float,
        rx_frames: int | None = None,
        boot_id: int = 0,
    ) -> float | None:
        """An uptime sample (and state; with telemetry, the count of frames the board took since its boot;
        with a heartbeat, its boot id) from the board: the reset detector. A boot id other than the one
        last heard says the board restarted, whatever its counts say (they are the new boot's: never
        judged against the old one's). Either count going back says so too; the frame count also when the
        restarted board then ran longer than the old one had, before the host reached it again (a board
        killed early in a run and restarted seconds before the host was back: its uptime did not go back,
        but it has taken only the new handshake's frames). A sample whose counts leapt ahead of what the
        board could have reached (:mod:`.leaps`) is dropped and counted: None is returned, the frame is not
        taken. Any other sample returns the host time it was made (:mod:`.made_at`), and a change of the
        board's state it carries is a :class:`StateEvent` of that time: a FAILSAFE read from a backlog after
        the host's own pause was stamped with its read, seconds after the board failed safe, and the
        run's outage then began at the read (a host paused 12 s said it was out for 0.03 s).

        ``kind`` is the sample's message class. A sample behind the newest of another kind by at most
        :data:`OVERTAKEN_MS`, its own kind's count not gone back, was overtaken on the way
        (:func:`_overtaken`): taken, its state not (it is older than the state held), no reset."""
        frames_out = self.counters.frames_out
        boot_changed = self._boot_changed(boot_id)
        if boot_changed is not None:
            self._renumbered()
        leap = (
            None if boot_changed is not None else self._leaps.refusal(uptime_ms, rx_frames, frames_out, now)
        )
        if leap is not None:
            self.counters.board_leaps += 1
            self._drop(now, f"a sample of the board's counts: {leap}")
            return None
        if self._leaps.reanchoring and boot_changed is None:
            self.counters.board_reanchors += 1
            logger.warning(
                "board counts consistently ahead of the first ones heard (uptime %d ms, %s frames taken): "
                "those were the absurd ones; taking these from now on",
                uptime_ms,
                rx_frames,
            )
            self._leaps.restart(uptime_ms, rx_frames, frames_out, now)
        stale = None if boot_changed is not None else self._stale(kind, uptime_ms, rx_frames, state)
        if stale is None:
            self._stale_in_a_row = 0
        else:
            self._stale_in_a_row += 1
            if self._stale_in_a_row < STALE_REANCHOR:
                self.counters.board_samples_stale += 1
                self._drop(now, f"a sample older than what the same boot of the board already said: {stale}")
                return None
            self.counters.board_reanchors += 1
            logger.warning(
                "board samples consistently behind the newest one heard of the same boot (%s): that one was "
                "the absurd one; taking these from now on",
                stale,
            )
            self._anchor_anew()
        last = self._last_uptime
        overtaken = boot_changed is None and _overtaken(last, self._last_uptime_of.get(kind), uptime_ms)
        self._last_uptime_of[kind] = uptime_ms
        if overtaken:
            assert last is not None and self._uptime_ms is not None
            self.counters.board_samples_overtaken += 1
            ran_ms = self._uptime_ms - behind(last, uptime_ms)  # before the newest: nothing else moves back
            return self._made_at.sample(ran_ms / 1000.0, now)
        self._last_uptime = uptime_ms
        last_rx = self._last_rx_frames
        if rx_frames is not None:
            self._last_rx_frames = rx_frames
        reply, self._reply_since_sample = self._reply_since_sample, None
        if reply is not None and boot_id and reply.boot_id and reply.boot_id != boot_id:
            reply = None  # the answer of the boot before: the cause of this one's reset is not known yet
        if boot_id:
            self._boot_id = boot_id
        age_from, self._age_check_from = self._age_check_from, None
        ran_ms = (
            uptime_ms
            if last is None or self._uptime_ms is None
            else self._uptime_ms + (uptime_ms - last) % _U32
        )
        evidence = None
        if last is not None and went_back(last, uptime_ms):
            evidence = f"its uptime went back from {last} ms to {uptime_ms} ms"
        elif last_rx is not None and rx_frames is not None and went_back(last_rx, rx_frames):
            evidence = f"its count of frames taken went back from {last_rx} to {rx_frames}"
        elif state is BoardState.BOOT and self.phase is Phase.READY:
            evidence = "it reports BOOT in the middle of a session"
        elif state is BoardState.BOOT and self._lost:
            evidence = "it reports BOOT after the link came back (it lost the session)"
        elif age_from is not None:
            evidence = self._younger_than_known(ran_ms, age_from)
        if boot_changed is not None:  # the board's own word, and what the counts say besides, if anything
            evidence = boot_changed if evidence is None else f"{boot_changed}; {evidence}"
        if evidence is None:
            self._uptime_ms = ran_ms
            made = self._made_at.sample(ran_ms / 1000.0, now)
            if state is not None:
                self._set_state(state, made)
            self._leaps.take(uptime_ms, rx_frames, frames_out, now, made)
            if not self._lost:  # a reconnect's samples before its answer are checked by the first after it
                self._ran = (ran_ms / 1000.0, now)
                if self._clock_base is None:
                    self._clock_base = self._ran
            return made
        self._made_at.forget_boot()
        self._last_uptime_of = {kind: uptime_ms}  # the new boot's: the old boot's other kind is no guide
        self._uptime_ms = uptime_ms  # the new boot's count: it starts from here
        made = self._made_at.sample(uptime_ms / 1000.0, now)
        # no board in hand since the new boot began (its uptime says), not only since this sample; no
        # earlier than the old boot was last heard, nor than this connection opened
        heard = -math.inf if self._ran is None else self._ran[1]
        self._boot_began = max(made - uptime_ms / 1000.0, heard, self._link_up_at)
        if state is not None:  # before the reset is seen: an armed board's reset is held by its state
            self._set_state(state, made)
        self._leaps.restart(uptime_ms, rx_frames, frames_out, now, made)  # the counts of a new boot
        self._last_rx_frames = rx_frames  # the new boot's count, or none yet: never the old boot's
        self._ran = (uptime_ms / 1000.0, now) if reply is not None else None  # else: the coming answer's
        self._clock_base = self._ran
        self._reset_seen(now, evidence)
        if reply is not None:  # the handshake that just happened already told why
            self._report_reset(now, reply.reset_cause, evidence, no_board_since=self._boot_began)
            return made
        self._reset_evidence = evidence
        if self.phase is Phase.READY:
            self.phase = Phase.HANDSHAKING
            self._hello(now)
        return made

    def _stale(
        self, kind: type, uptime_ms: int, rx_frames: int | None, state: BoardState | None
    ) -> str | None:
        """Why a sample is an old frame of the boot the session has — replayed, or held back on the way for
        longer than :data:`OVERTAKEN_MS` — rather than a reset (counts gone back); None if it is not. Only
        where it can be told: the board says its boot id (a reset changes it: the next Heartbeat tells), the
        sample does not say BOOT (a restarted board says it until a handshake, whatever its boot id: a
        simulated one may draw the same again), and the session runs on (no handshake since the last
        sample, whose answer any restart would have come with). One such frame once disarmed the board,
        counted a reset that never happened and, a Telemetry, was held as the board's word on now."""
        if (
            not self._boot_id
            or state is BoardState.BOOT
            or self.phase is not Phase.READY
            or self._lost
            or self._reply_since_sample is not None
            or self._age_check_from is not None
        ):
            return None
        last = self._last_uptime
        if (
            last is not None
            and went_back(last, uptime_ms)
            and not _overtaken(last, self._last_uptime_of.get(kind), uptime_ms)
        ):
            return f"its uptime {uptime_ms} ms is behind the {last} ms already heard"
        last_rx = self._last_rx_frames
        if last_rx is not None and rx_frames is not None and went_back(last_rx, rx_frames):
            return f"its count of frames taken ({rx_frames}) is behind the {last_rx} already heard"
        return None

    def _anchor_anew(self) -> None:
        """The boot's counts anchored on the next sample taken: the newest ones heard were the absurd ones
        (one sample ahead of the board within the leaps' slack, and every honest one after it behind)."""
        self._last_uptime = self._last_rx_frames = self._uptime_ms = None
        self._last_uptime_of.clear()
        self._leaps = LeapCheck()
        self._made_at.forget_boot()
        self._stale_in_a_row = 0

    def _reset_seen(self, now: float, evidence: str) -> None:
        """What every reset seen does before it is reported: an armed board's reset held for the caller
        (:class:`PendingReset`), the commands and transfers in flight abandoned."""
        if self.armed and self.state is not BoardState.ARMED:
            self.armed = False
            self.pending_reset = PendingReset(now, evidence)
        # Commands in flight were for the board before its reset: a retry landing on the board after it
        # (its answer cache empty) would be carried out there — an Arm from the old session arming the new
        # one before the host has seen the reset. They fail now; the caller sends anew if it still wants.
        why = f"the board reset ({evidence})"
        self.commands.abandon(now, why)
        self._transfers.abandon(why)

    def _boot_changed(self, boot_id: int) -> str | None:
        """The evidence of a reset if ``boot_id`` (0: the board does not say) is not the boot id last
        heard from the board, else None. Raises :class:`LinkError` when boot ids replaced come back again and
        again (:func:`_twin_check`): two boards answer as one."""
        known = self._boot_id
        if not boot_id or known is None or boot_id == known:
            return None
        self._twin_check(known, boot_id)
        return f"its boot id changed from {known:#010x} to {boot_id:#010x}"

    def _twin_check(self, known: int, boot_id: int) -> None:
        """The boot id ``known`` gives way to ``boot_id``: a :class:`LinkError` when ``boot_id`` is one
        already replaced, for the :data:`TWIN_RETURNS` th time within :data:`TWIN_WINDOW_S`. A board draws
        its boot id anew at each boot (the firmware from its count of boots in EEPROM), so one board's ids
        never come back — two boards on one port or node id (a second board on a CAN bus configured with
        this one's node id) interleave theirs: each change was taken for a reset, hundreds of them, the
        board re-armed each time (both boards commanded), until the run ended "lost" with nothing naming
        the cause. A few returns are allowed (an emulator restarted with its seed draws its ids again)."""
        now = self._now
        if boot_id in self._replaced_boots:
            returns = self._boot_returns
            returns.append(now)
            if len(returns) == returns.maxlen and now - returns[0] <= TWIN_WINDOW_S and not self.twins_said:
                self.twins_said = True  # once: the way out's Disarm (to both) may still be answered
                raise LinkError(
                    f"two boards answer as one: boot ids {known:#010x} and {boot_id:#010x} come and go "
                    f"{len(returns)} times within {now - returns[0]:.2f} s (two boards on one port, or on "
                    "one CAN bus with one node id?)"
                )
        if known not in self._replaced_boots:
            self._replaced_boots.append(known)

    def _younger_than_known(self, uptime_ms: int, hello_at: float) -> str | None:
        """Why the board that answered a reconnect's handshake (its Hello sent at ``hello_at``) cannot be
        the one the session had — its uptime in the first sample after the answer is shorter than the
        board had certainly run by then: as long as when last heard of (its last sample taken, or 0 s at
        its first answer) and the host time since, less :data:`AGE_SLACK_S`, its clock allowed to run
        ``CLOCK_RATE`` slow — or None. It restarted while the link was down: a process killed and started
        again, a board power-cycled, on the same port. Counts that went back tell it only when the new
        boot had not run past the old one's last sample; a board killed moments after the first handshake
        (no sample yet) and restarted seconds before the host found it again passed for the same board,
        its reset never reported. Measured from the last sample, not from the boot: an emulated board's
        clock falls behind the wall when its process is not run (simavr's harness under load), and over a
        whole run that lag would pass for a restart; over an outage it stays within the slack. A board
        whose clock its own samples showed slower than the host's (:meth:`_board_rate`: an uncalibrated RC
        oscillator runs up to 10 % slow) is allowed that rate: at the 1 % alone, a board 10 % slow was
        reported reset after every outage longer than 5.5 s."""
        if self._ran is None:
            return None
        ran_s, heard_at = self._ran
        since_s = hello_at - heard_at  # the sample left the board after our Hello reached it
        uptime_s = uptime_ms / 1000.0
        rate = self._board_rate()
        if (uptime_s - ran_s) * CLOCK_RATE / rate + AGE_SLACK_S >= since_s:
            return None
        slow = f", its clock taken to run at {rate:.1%} of the host's" if rate < 1.0 else ""
        return (
            f"its uptime ({uptime_ms} ms) is shorter than the {ran_s + since_s * rate:.3f} s the board had "
            f"run (it was at {ran_s:.3f} s at t={heard_at:.3f} s{slow}): it restarted while the link was down"
        )

    def _forget_boot(self) -> None:
        """A new boot of the board, seen before any sample of it: the counts heard so far were the old
        boot's (its next sample anchors them anew)."""
        self._last_uptime = self._last_rx_frames = self._uptime_ms = None
        self._last_uptime_of.clear()
        self._leaps = LeapCheck()
        self._ran = self._clock_base = None
        self._age_check_from = None
        self._made_at.forget_boot()

    def _board_rate(self) -> float:
        """How fast the board's clock ran against the host's over this boot's samples (board s per host s),
        at most 1 — a board's clock seeming fast is no reason to expect more of it, an emulator's falls
        behind when it is not run — at least :data:`SLOWEST_RATE`; 1 until they spread over
        :data:`RATE_BASELINE_S`."""
        base, ran = self._clock_base, self._ran
        if base is None or ran is None or ran[1] - base[1] < RATE_BASELINE_S:
            return 1.0
        return min(max((ran[0] - base[0]) / (ran[1] - base[1]), SLOWEST_RATE), 1.0)

    def _set_state(self, state: BoardState, now: float) -> None:
        old, self.state = self.state, state
        self._state_changed(old, now)

    def _state_changed(self, old: BoardState | None, now: float) -> None:
        """The board's state is :attr:`state` now, ``old`` before: told (a :class:`StateEvent`) if it
        changed."""
        state = self.state
        if state is old or state is None:
            return
        self._emit(StateEvent(now, old, state))
        if state is BoardState.FAILSAFE:
            logger.warning("board in FAILSAFE (its link watchdog fired); arm() to recover")

    def _report_reset(
        self,
        now: float,
        cause: ResetCause,
        evidence: str,
        in_session: bool = True,
        no_board_since: float | None = None,
    ) -> None:
        self.counters.resets += 1
        if self.pending_reset is not None:
            self.pending_reset.cause = cause
        self._emit(BoardResetEvent(now, cause, evidence, in_session, no_board_since))
        more = self._reset_warnings.due(now)  # a reset storm: every one counted and an event, a line a second
        if more is None:
            return
        since = f" (and {more} more resets since the last warning)" if more else ""
        logger.warning("board reset (cause %s): %s%s", cause.name, printable(evidence), since)

    # ------------------------------------------------------------------ handshake
    def _hello(self, now: float) -> None:
        if len(self.hellos):
            return  # one is already on its way
        hello = Hello(
            protocol_version=PROTOCOL_VERSION,
            schema_hash=self.config.schema_hash,
            **asdict(self.config.identity),
        )
        _, data = self.hellos.send(hello, now)
        self._put(data, now)

    def _on_hello_settled(self, cmd: Command) -> None:
        now = self._now
        if cmd.state is CommandState.ACKED:
            self._earlier_tries = cmd.tries - 1  # answers to them may still come (_on_hello_reply_frame)
            self._on_hello_reply(cmd.reply, now)
        elif self.phase is Phase.HANDSHAKING:  # not abandoned by link_down: the board never answered
            self.failure = LinkTimeout(
                f"the board did not answer the handshake ({cmd.failure}){self.heard_instead()}"
            )
            self.link_down(now, str(self.failure))

    def heard_instead(self) -> str:
        """What came back in place of the board's answer since the link came up, said for the operator
        (empty if nothing did): the host's own frames (the port echoes), or another host's."""
        echoes = self.counters.echoes - self._echoes_at_link_up
        others = self.counters.host_frames - self._host_frames_at_link_up
        said = ""
        if echoes:
            said += (
                f"; {echoes} of the frames the host wrote came back as written: the port echoes what the "
                "host sends (a loopback plug, TX joined to RX, an echoing RS-485 adapter) — is the board "
                "on this port, and powered?"
            )
        if others:
            said += (
                f"; {others} frames only a host sends came from the far side: another host is on the "
                "line, not a board (crossed wires?)"
            )
        return said

    def _on_hello_reply(self, reply: HelloReply, now: float) -> None:
        try:
            info = BoardInfo.from_reply(reply)
        except FieldRangeError as exc:
            # an identity string the frame's decoder takes but no accessory has (a NUL inside): it raised
            # out of feed(), the Hello settled and the handshake half applied, naming no HelloReply
            self.phase = Phase.INCOMPATIBLE
            self.failure = HandshakeError(
                f"the board's HelloReply carries an identity no accessory has ({exc}): not a board this "
                "host can name or command"
            )
            return
        ours = (PROTOCOL_VERSION, self.config.schema_hash)
        if (reply.protocol_version, reply.schema_hash) != ours:
            self.phase = Phase.INCOMPATIBLE
            self.failure = HandshakeError(
                f"incompatible board {info.describe()}: it speaks protocol {reply.protocol_version} "
                f"with schema hash {reply.schema_hash:#010x}; this host speaks protocol {ours[0]} with "
                f"schema hash {ours[1]:#010x}"
            )
            return
        previous = self.info
        if previous is not None and (previous.identity, previous.n_units) != (info.identity, info.n_units):
            self.phase = Phase.INCOMPATIBLE  # never command another board as if it were the one we had
            self.failure = HandshakeError(
                f"another board answered the new handshake: {info.describe()}; the session was with "
                f"{previous.describe()}"
            )
            return
        first = previous is None
        boot_changed = None if self._reset_evidence is not None else self._boot_changed(reply.boot_id)
        if reply.boot_id:
            self._boot_id = reply.boot_id
        if boot_changed is not None:  # a new boot: nothing heard before it is its word
            self._forget_boot()
            self._renumbered()
        if self._ran is None:  # the first answer of this boot: it had begun by now
            self._ran = (0.0, now)
        self.info = info
        self.phase = Phase.READY
        self.counters.handshakes += 1
        self._reply_since_sample = reply
        self._setpoint_slot = -math.inf
        # The reset is told before the state it left the board in (and judged by that state: an armed
        # board's reset is held for the caller): an ARMED board found DISARMED by the handshake after a
        # reset is that reset's doing, and a run told the change first saw a Disarm no command of the
        # host's asked for — two faults for one reset, one of them false.
        old_state, self.state = self.state, reply.state
        # A restart seen before (or told by) the first answer — a board that hung or browned out at its boot,
        # a heartbeat of the boot before: the host never had the board — it had none from its first try
        # on, not an outage of 0.02 s from this answer (one such board was silent 0.55 s before it).
        no_board_since = self._reaching_since if first else None
        if self._reset_evidence is not None:
            evidence = _before_first_session(self._reset_evidence, no_board_since)
            began = no_board_since if first else self._boot_began
            self._report_reset(now, reply.reset_cause, evidence, not first, began)
            self._reset_evidence = None
        elif boot_changed is not None:
            self._reset_seen(now, boot_changed)
            evidence = _before_first_session(boot_changed, no_board_since)
            self._report_reset(now, reply.reset_cause, evidence, not first, no_board_since)
        elif first and reply.reset_cause is not ResetCause.POWER_ON:
            evidence = _before_first_session("reported at connect (before this session)", no_board_since)
            self._report_reset(now, reply.reset_cause, evidence, False, no_board_since)
        self._state_changed(old_state, now)
        reconnect = self._lost
        rearm = self._armed_at_loss and self.config.rearm_on_reconnect  # a board that reset too: asked for
        self.counters.reconnects += reconnect
        self._lost = self._armed_at_loss = False
        if reconnect and boot_changed is None:  # the board that answered may have restarted meanwhile
            self._age_check_from = self._link_up_at
        self._emit(ConnectedEvent(now, info, self.counters.reconnects))
        if reconnect and rearm:
            cmd, data = self.commands.send(Arm(), now)
            self._auto[id(cmd)] = "re-arm after reconnect"
            self._put(data, now)

    # ------------------------------------------------------------------ commands
    def _on_settled(self, cmd: Command) -> None:
        now = self._now
        if cmd.latency is not None:
            self.rtt.add(cmd.latency)
        if isinstance(cmd.message, (Arm, Disarm)) and cmd.ok:  # accepted means executed: the state is known
            self._set_state(BoardState.ARMED if isinstance(cmd.message, Arm) else BoardState.DISARMED, now)
        if isinstance(cmd.message, Arm) and cmd.ok:
            self.armed = True
            self.arm_acked_at = now
            self.pending_reset = None
        why = self._auto.pop(id(cmd), None)
        if why is not None:
            detail = "" if cmd.ok else (cmd.reason.name if cmd.reason is not None else cmd.failure)
            self._emit(CommandEvent(now, why, cmd.ok, detail))
        if isinstance(cmd.message, CalibrationRequest) and not cmd.ok:
            self._transfers.request_failed(cmd)

    def _on_late_answer(self, cmd: Command) -> None:
        """A superseded command's answer came late: it says whether the board carried it out (told as a
        :class:`CommandEvent`; it said before it was not known). The board's state is left to the newer
        command and the telemetry: this answer is older than both."""
        now = self._now
        name = type(cmd.message).__name__
        newer = cmd.superseded_by
        by = "" if newer is None else f" by {type(newer.message).__name__} (seq {newer.seq})"
        what = f"{name} (seq {cmd.seq}), superseded{by}"
        self._emit(CommandEvent(now, what, bool(cmd.carried_out), cmd.failure))
        logger.info("%s: %s", what, cmd.failure)

    def _on_calibration_data(self, frame: Frame, now: float) -> None:
        """A fragment of a download (B→H, reliable): acknowledge it, once, and reassemble."""
        answer = self._transfers.answer(frame, now)
        self.counters.calibration_answers += 1
        self._send(answer, now)

    # ================================================================== internals
    def _require_session(self) -> None:
        if self.phase is not Phase.READY:
            raise LinkError(f"no session with the board (link {self.phase.value})")

    def _check_setpoint(self, message: ActuatorSetpoint | RawPulses) -> bytes:
        """``message`` checked and encoded, once, before anything is held: the body
        :meth:`_send_setpoint` numbers and sends (now, or at its slot if it is not replaced first)."""
        if not isinstance(message, (ActuatorSetpoint, RawPulses)):
            raise ProtocolError(f"{type(message).__name__} is not a setpoint (ActuatorSetpoint or RawPulses)")
        body = self.framer.prepare(message)  # FieldRangeError for NaN / out-of-range values
        info = self.info
        if info is None:
            return body
        if isinstance(message, ActuatorSetpoint) and len(message.units) != info.n_units:
            raise ProtocolError(
                f"ActuatorSetpoint for {len(message.units)} units; the board has {info.n_units}"
            )
        if isinstance(message, RawPulses) and len(message.pulses_us) != info.n_channels:
            raise ProtocolError(
                f"RawPulses for {len(message.pulses_us)} channels; the board has {info.n_channels}"
            )
        return body

    def _check_unit(self, unit: int) -> None:
        self._require_session()
        assert self.info is not None
        if isinstance(unit, bool) or not isinstance(unit, int) or not 0 <= unit < self.info.n_units:
            raise ProtocolError(f"unit {unit!r} does not exist (the board has {self.info.n_units})")

    def _send_setpoint(self, body: bytes, now: float) -> None:
        _, data = self.framer.send_prepared(body)
        self._put(data, now)
        self.counters.setpoints_sent += 1
        self._setpoint_slot = now + 1.0 / self._setpoint_rate()

    def _setpoint_rate(self) -> float:
        if self.config.max_setpoint_rate_hz is not None:
            return self.config.max_setpoint_rate_hz
        frame_rate = self.info.frame_rate_hz if self.info is not None else 0
        return 2.0 * frame_rate if frame_rate > 0 else math.inf

    def _send(self, message: Any, now: float) -> None:
        _, data = self.framer.encode(message)
        self._put(data, now)

    def _put(self, data: bytes, now: float) -> None:
        if data:
            self._out += data
            self._last_tx = now
            self.counters.frames_out += data.count(0)  # every frame ends with its only 0x00
            self._written.wrote(data, now)

    def _take(self) -> bytes:
        out = bytes(self._out)
        self._out.clear()
        return out

    def _emit(self, event: Event) -> None:
        self._events.append(event)

    def _drop(self, now: float, what: str) -> None:
        """A well-formed frame not taken (already counted by its kind): logged at most once per
        :data:`DROP_WARN_EVERY_S` of host time, the next warning saying how many more were dropped."""
        more = self._drop_warnings.due(now)
        if more is None:
            return
        since = f" (and {more} more dropped since the last warning)" if more else ""
        logger.warning("board frame dropped: %s%s", what, since)


Receive = Callable[[Session, Frame, float], None]
"""A received message's handler: ``(session, frame, now)``."""

RECEIVE: dict[type[Message], Receive] = {
    # board to host
    HelloReply: Session._on_hello_reply_frame,  # settles the handshake's Hello
    Telemetry: Session._on_telemetry,
    Heartbeat: Session._on_heartbeat,
    Log: Session._on_log,
    CalibrationData: Session._on_calibration_data,  # a download's fragment, acknowledged
    EscCalibrationStatus: Session._on_esc_calibration_status,
    Ack: Session._on_answer,
    Nack: Session._on_answer,
    # host to board, come back
    Hello: Session._on_not_ours,
    Arm: Session._on_not_ours,
    Disarm: Session._on_not_ours,
    SetMode: Session._on_not_ours,
    EscCalibrate: Session._on_not_ours,
    ActuatorSetpoint: Session._on_not_ours,
    RawPulses: Session._on_not_ours,
    CalibrationRequest: Session._on_not_ours,
}
"""What the host's session does with each message of the catalogue (``protocol.messages.CATALOGUE``) that
arrives from the board, by type. Every catalogue message has an entry — ``tests/test_message_dispatch.py``
fails naming one that has not (docs/protocol.md, "Adding a message")."""

HOST_ONLY: frozenset[type[Message]] = frozenset(
    cls for cls, receive in RECEIVE.items() if receive is Session._on_not_ours
)
"""The kinds of frame only a host sends: one arriving is a host's, this one's come back or another's."""
HOST_WRITES: frozenset[type[Message]] = HOST_ONLY | {Heartbeat, Ack, Nack, CalibrationData}
"""The kinds of frame this host writes: the host-to-board ones and those both ends send (its heartbeats,
its answers to a download's fragments, an upload's fragments). One of them arriving may be the host's own
come back (:mod:`.echoes`)."""


def _overtaken(newest: int | None, own_last: int | None, uptime_ms: int) -> bool:
    """Whether a sample at ``uptime_ms`` (ms) is behind the ``newest`` of any kind by at most
    :data:`OVERTAKEN_MS` while its own kind's count (``own_last``) did not go back: a frame another kind
    overtook on the way (CAN by priority), not a board that reset."""
    if newest is None or not went_back(newest, uptime_ms) or behind(newest, uptime_ms) > OVERTAKEN_MS:
        return False
    return own_last is None or not went_back(own_last, uptime_ms)


def _before_first_session(evidence: str, no_board_since: float | None) -> str:
    """``evidence`` of a reset, said of one seen before the first session when ``no_board_since`` (host
    s: the host's first try to reach the board) is given."""
    if no_board_since is None:
        return evidence
    return (
        f"{evidence}: it restarted before it answered the host's first handshake (no board in hand since "
        f"t={no_board_since:.3f} s)"
    )
