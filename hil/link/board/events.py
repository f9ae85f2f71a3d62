"""What the board client reports, as it happens: one frozen dataclass per kind of event.

Every event carries ``t``, the host's receive time on the client's clock (seconds; lockstep or wall), so a
run log can put telemetry, logs and link trouble on one time axis. Events reach the caller through
``BoardClient.service()`` / ``drain_events()`` (a bounded queue; overflow is counted) and, if given, the
``on_event`` callback (called from the thread that processed the bytes).
"""

from __future__ import annotations

from dataclasses import dataclass

from protocol.aoa import AccessoryIdentity
from protocol.messages import BoardState, EscCalibrationStatus, HelloReply, Log, ResetCause, Telemetry

_UNPRINTABLE = {
    c: f"\\x{c:02x}" if c < 0x100 else f"\\u{c:04x}"
    for c in (
        *range(0x20),
        *range(0x7F, 0xA0),
        0x061C,
        *range(0x200E, 0x2010),
        *range(0x202A, 0x202F),
        *range(0x2066, 0x206A),
    )
    if c != 0x09
}
"""Control characters (C0 but the tab, DEL, C1) and bidirectional marks, embeddings, overrides and
isolates, each as its escape: what a board says (its Log text, its identity strings) goes to the
operator's terminal, where ``ESC [2J`` cleared the screen, a CR over-wrote the host's own line and
``ESC [8m`` hid what followed; U+202E and U+2067 turn text round."""


def printable(text: str) -> str:
    """``text`` a board sent with :data:`_UNPRINTABLE` escaped, for a log line or a message (events keep
    the board's text as it was)."""
    return text.translate(_UNPRINTABLE)


@dataclass(frozen=True, slots=True)
class BoardInfo:
    """Who answered the handshake (``HelloReply``): identity, outputs, protocol, last reset cause."""

    protocol_version: int
    schema_hash: int
    reset_cause: ResetCause
    state: BoardState
    n_units: int
    frame_rate_hz: int
    identity: AccessoryIdentity
    firmware_build: str
    boot_id: int = 0
    """The board's boot it answered from (new at every boot; 0: a board that does not say)."""

    @classmethod
    def from_reply(cls, reply: HelloReply) -> BoardInfo:
        return cls(
            protocol_version=reply.protocol_version,
            schema_hash=reply.schema_hash,
            reset_cause=reply.reset_cause,
            state=reply.state,
            n_units=reply.n_units,
            frame_rate_hz=reply.frame_rate_hz,
            identity=AccessoryIdentity.from_message(reply),
            firmware_build=reply.firmware_build,
            boot_id=reply.boot_id,
        )

    @property
    def n_channels(self) -> int:
        """Pulse outputs: gimbal 0, rotor 0, gimbal 1, rotor 1, ..."""
        return 2 * self.n_units

    def describe(self) -> str:
        """The board in one line, for logs and messages: its strings :func:`printable`."""
        ident = self.identity
        boot = f", boot {self.boot_id:#010x}" if self.boot_id else ""
        return printable(
            f"{ident.manufacturer} {ident.model} {ident.version} (serial {ident.serial or '-'}, build "
            f"{self.firmware_build or '-'}{boot}): {self.n_units} units, {self.frame_rate_hz} Hz frames"
        )


@dataclass(frozen=True, slots=True)
class TelemetryEvent:
    """A ``Telemetry`` frame from the board."""

    t: float
    telemetry: Telemetry


@dataclass(frozen=True, slots=True)
class LogEvent:
    """A ``Log`` frame from the board (state changes, faults, refused commands)."""

    t: float
    log: Log


@dataclass(frozen=True, slots=True)
class EscCalibrationEvent:
    """An ``EscCalibrationStatus`` from the board: where its ESC endpoint procedure is."""

    t: float
    status: EscCalibrationStatus


@dataclass(frozen=True, slots=True)
class StateEvent:
    """The board's state changed (seen in a HelloReply, Heartbeat or Telemetry). ``old`` is None for the
    first state seen. ``new is BoardState.FAILSAFE``: the board's link watchdog fired; ``arm()`` recovers."""

    t: float
    old: BoardState | None
    new: BoardState


@dataclass(frozen=True, slots=True)
class BoardResetEvent:
    """The board reset: ``cause`` from its HelloReply, ``evidence`` how the host noticed (its uptime went
    backwards, it reported BOOT mid-session, or — ``during_session`` False — it reported a non-power-on
    reset cause when the host first connected, or restarted before it answered the first handshake).
    ``no_board_since``: the host time (s) since which the host has had no board in hand, not only since this
    event: for a restart seen before the first session, the host's first try to reach the board; for one in
    a session, the new boot's start by its uptime (no earlier than the old boot was last heard, nor than the
    connection opened); None when not known."""

    t: float
    cause: ResetCause
    evidence: str
    during_session: bool = True
    no_board_since: float | None = None


@dataclass(frozen=True, slots=True)
class ConnectedEvent:
    """A session is (re-)established: the handshake succeeded. ``reconnects`` counts link losses
    recovered so far (0 on the first connection)."""

    t: float
    info: BoardInfo
    reconnects: int


@dataclass(frozen=True, slots=True)
class LinkLostEvent:
    """The transport failed (port vanished, bus error) or the board stopped answering the handshake;
    the client reconnects with back-off."""

    t: float
    reason: str


@dataclass(frozen=True, slots=True)
class SilenceEvent:
    """No valid frame from the board since ``since`` (``ended`` False), or frames again (``ended`` True).
    A board that heartbeats at 5 Hz is silent only if it hung, lost power or the link is cut."""

    t: float
    since: float
    ended: bool


@dataclass(frozen=True, slots=True)
class CommandEvent:
    """A command the client sent on its own (a re-arm the caller asked for on reconnect) settled; or a
    command a newer one superseded was answered late (``ok``: the board carried it out; ``detail`` says
    what it did): superseded, it had failed saying that was not known."""

    t: float
    command: str
    ok: bool
    detail: str = ""


Event = (
    TelemetryEvent
    | LogEvent
    | EscCalibrationEvent
    | StateEvent
    | BoardResetEvent
    | ConnectedEvent
    | LinkLostEvent
    | SilenceEvent
    | CommandEvent
)
