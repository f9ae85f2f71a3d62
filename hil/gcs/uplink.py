"""The uplink: commands from the page, checked by the server, carried out by the host on its control tick.

Commands (``POST /api/command``, a JSON object; docs/gcs.md, "Uplink"):

``{"command": "arm"}``       Arm through the board protocol (acknowledged by the board)
``{"command": "disarm"}``    Disarm (acknowledged): rotors to the safe pulse, gimbals hold; the run goes on
``{"command": "abort"}``     Disarm, then end the run once the board's telemetry shows it disarmed; when the
                             link cannot carry the Disarm the host lets go of the board and its link
                             watchdog fails it safe within its timeout
``{"command": "hold"}``      hold the attitude estimated now (the host's reference stops there)
``{"command": "slew", "roll_deg": r, "pitch_deg": p, "yaw_deg": y}``
                             slew to the attitude R = Rz(yaw) Ry(pitch) Rx(roll), body → inertial, within
                             the scenario's rate and acceleration limits

The server thread only parses and queues (:meth:`Uplink.submit`, bounded: a full inbox answers 503); the
control thread drains the inbox at the start of each tick (:meth:`Uplink.service`), so a command never
races the control law. Every step is an ``events.jsonl`` record ``{"kind": "command", "origin": "gcs",
"id": n, "command": ..., "status": ...}``: ``sent`` (to the board) then ``acked`` / ``nacked`` /
``failed`` (the board protocol's answer), or ``applied`` / ``refused`` (host-side), each with details; the
page shows them against the id the POST returned. Requests the server turns away (wrong token, foreign
origin) are logged the same way with ``status: "rejected"``.
"""

from __future__ import annotations

import json
import math
import threading
from collections import deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from hil import so3
from hil.runtime.observer import RunAborted
from protocol.errors import HilError, InputFormatError
from protocol.messages import Arm, BoardState, Disarm
from protocol.reliable import CommandState

if TYPE_CHECKING:
    from hil.runtime.host import Host
    from protocol.reliable import Command as BoardCommand

COMMANDS = ("arm", "disarm", "abort", "hold", "slew")
MAX_BODY = 4096  # bytes of a command request
INBOX = 16  # commands waiting for the next control tick; more answer 503
REJECTED_LOG = 64  # turned-away requests waiting to be logged; more are counted only
ABORT_CONFIRM_S = 0.5  # an abort waits this long after the Disarm's ack for telemetry that shows it
ANGLE_RANGE = {"roll_deg": 180.0, "pitch_deg": 90.0, "yaw_deg": 180.0}


@dataclass(frozen=True)
class Command:
    """One accepted request. ``target``: (roll, pitch, yaw) degrees for ``slew``."""

    id: int
    name: str
    target: tuple[float, float, float] | None = None
    remote: str = ""


def euler_zyx(roll_deg: float, pitch_deg: float, yaw_deg: float) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll) (3, 3), body → inertial (the aerospace yaw-pitch-roll sequence)."""
    r, p, y = (math.radians(a) for a in (roll_deg, pitch_deg, yaw_deg))
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])  # fmt: skip


def parse_command(body: bytes, command_id: int, remote: str = "") -> Command:
    """A request body as a :class:`Command`; :class:`InputFormatError` saying what is wrong otherwise."""
    where = "POST /api/command"
    if len(body) > MAX_BODY:
        raise InputFormatError(f"body of {len(body)} bytes (at most {MAX_BODY})", where)
    try:
        doc = json.loads(body)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputFormatError(f"not JSON: {exc}", where) from None
    if not isinstance(doc, dict):
        raise InputFormatError("expected a JSON object", where)
    name = doc.get("command")
    if name not in COMMANDS:
        raise InputFormatError(f"command must be one of {', '.join(COMMANDS)}, got {name!r}", where)
    extra = set(doc) - {"command", *(ANGLE_RANGE if name == "slew" else ())}
    if extra:
        raise InputFormatError(f"unknown field(s) for {name}: {', '.join(sorted(extra))}", where)
    if name != "slew":
        return Command(command_id, name, remote=remote)
    angles = []
    for key, limit in ANGLE_RANGE.items():
        value = doc.get(key)
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise InputFormatError(f"{key} must be a number of degrees, got {value!r}", where)
        if abs(value) > limit:
            raise InputFormatError(f"{key} must lie within ±{limit:g}°, got {value}", where)
        angles.append(float(value))
    return Command(command_id, name, (angles[0], angles[1], angles[2]), remote)


@dataclass
class _Pending:
    command: Command
    handle: BoardCommand
    sent_t: float


@dataclass
class UplinkStats:
    accepted: int = 0
    inbox_full: int = 0
    rejected: int = 0  # requests turned away by the server (token, origin, host, format)
    rejected_unlogged: int = 0  # ... beyond REJECTED_LOG between two ticks


@dataclass
class Uplink:
    """The inbox (server threads) and its executor (the control thread)."""

    stats: UplinkStats = field(default_factory=UplinkStats)

    def __post_init__(self) -> None:
        self._lock = threading.Lock()
        self._inbox: deque[Command] = deque()
        self._rejected: deque[dict[str, Any]] = deque()
        self._next_id = 1
        self._pending: list[_Pending] = []
        self._abort: _Pending | None = None
        self.host: Host | None = None

    # ------------------------------------------------------------------ server threads
    def submit(self, body: bytes, remote: str = "") -> Command | None:
        """Parse and queue a request; the command, or None when the inbox is full (InputFormatError for a
        malformed request)."""
        with self._lock:
            if len(self._inbox) >= INBOX:
                self.stats.inbox_full += 1
                return None
            command = parse_command(body, self._next_id, remote)
            self._next_id += 1
            self._inbox.append(command)
            self.stats.accepted += 1
            return command

    def reject(self, reason: str, remote: str, detail: str = "") -> None:
        """A request the server turned away, to be logged in the run's events on the next tick."""
        with self._lock:
            self.stats.rejected += 1
            if len(self._rejected) >= REJECTED_LOG:
                self.stats.rejected_unlogged += 1
                return
            self._rejected.append({"reason": reason, "remote": remote, "detail": detail})

    # ------------------------------------------------------------------ the control thread
    def service(self, host: Host, t: float) -> None:
        """Log rejections, carry out queued commands, settle answered ones; raises :class:`RunAborted`
        once an abort's Disarm is answered (or cannot be sent)."""
        with self._lock:
            commands = list(self._inbox)
            self._inbox.clear()
            rejected = list(self._rejected)
            self._rejected.clear()
        for r in rejected:
            host.events.write(t, "command", origin="gcs", id=None, command=None, status="rejected", **r)
        for command in commands:
            self._apply(host, t, command)
        still = []
        for p in self._pending:
            if p.handle.done:
                self._settle(host, t, p)
            else:
                still.append(p)
        self._pending = still
        abort = self._abort
        if abort is not None and abort.handle.done:
            self._end_abort(host, t, abort)

    def _end_abort(self, host: Host, t: float, abort: _Pending) -> None:
        """End the run once the board says it is no longer armed (its telemetry after the Disarm's ack),
        or at once if the Disarm failed (the board's link watchdog then fails it safe when the host lets
        go); at most :data:`ABORT_CONFIRM_S` after the ack."""
        n = abort.command.id
        if not abort.handle.ok:
            raise RunAborted(f"from the ground station (command {n}: the Disarm failed; the board's link "
                             "watchdog fails it safe)")  # fmt: skip
        tel = host.client.telemetry
        settled = abort.handle.settled_at
        if (
            tel is not None
            and tel.state is BoardState.ARMED
            and (settled is None or t - settled < ABORT_CONFIRM_S)
        ):
            return  # acknowledged; wait for the telemetry that shows it
        state = "no telemetry" if tel is None else tel.state.name
        raise RunAborted(f"from the ground station (command {n}: board disarmed, telemetry says {state})")

    def _log(self, host: Host, t: float, command: Command, status: str, **fields: Any) -> None:
        host.events.write(t, "command", origin="gcs", id=command.id, command=command.name, status=status,
                          remote=command.remote, **fields)  # fmt: skip

    def _apply(self, host: Host, t: float, command: Command) -> None:
        if self._abort is not None:
            self._log(host, t, command, "refused", reason="the run is being aborted")
            return
        name = command.name
        if name in ("arm", "disarm", "abort"):
            message = Arm() if name == "arm" else Disarm()
            try:  # through the host: its own re-arming yields to the operator's disarm
                handle = host.arm(t) if name == "arm" else host.disarm(t)
            except HilError as exc:
                self._log(host, t, command, "refused", reason=f"link: {exc}")
                if name == "abort":
                    raise RunAborted(f"from the ground station (command {command.id}: the link is down; "
                                     "the board's link watchdog fails it safe)") from exc  # fmt: skip
                return
            pending = _Pending(command, handle, t)
            self._log(host, t, command, "sent", message=type(message).__name__)
            if name == "abort":
                self._abort = pending
            self._pending.append(pending)
            return
        if name == "hold":
            reason = host.retarget(t, None)
        else:
            assert command.target is not None
            reason = host.retarget(t, euler_zyx(*command.target))
        if reason is not None:
            self._log(host, t, command, "refused", reason=reason)
            return
        assert host.slew is not None and host.target is not None
        self._log(host, t, command, "applied", target_r=so3.log(host.target).tolist(),
                  slew_s=host.slew.duration_s, target_euler_deg=command.target)  # fmt: skip

    def _settle(self, host: Host, t: float, p: _Pending) -> None:
        """The board's answer, as the protocol settled it: acked, nacked (with its reason) or failed."""
        handle = p.handle
        after_ms = (t - p.sent_t) * 1e3
        if handle.state is CommandState.ACKED:
            self._log(host, t, p.command, "acked", after_ms=after_ms, seq=handle.seq)
        elif handle.state is CommandState.NACKED:
            reason = None if handle.reason is None else handle.reason.name
            self._log(host, t, p.command, "nacked", reason=reason, after_ms=after_ms, seq=handle.seq)
        else:
            self._log(host, t, p.command, "failed", reason=handle.failure, after_ms=after_ms, seq=handle.seq)
