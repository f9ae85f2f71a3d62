"""The operator's commands to a run — arm, disarm, abort, hold, slew — carried out on the control thread,
whoever sends them: the ground station's page (:mod:`hil.gcs.uplink` queues them from its server
threads), a fault campaign's drawn schedule (:mod:`hil.montecarlo.faults`), a test.

==========  ==========================================================================================
command     what the run does
==========  ==========================================================================================
``arm``     Arm through the board protocol (acknowledged by the board); after an operator's Disarm the
            host warms up again (spin-up, checks) and plans a new slew to its target
            (:meth:`hil.runtime.host.Host.arm`)
``disarm``  Disarm (acknowledged): rotors to the safe pulse, gimbals hold; the run is *suspended* — no
            reference, no requirement clock, no re-arming on the host's own account — until the
            operator's Arm (:meth:`hil.runtime.host.Host.disarm`)
``abort``   Disarm, then end the run once the board's telemetry shows it disarmed; when the link cannot
            carry the Disarm the host lets go of the board and its link watchdog fails it safe within
            its timeout
``hold``    hold the attitude estimated now (the host's reference stops there)
``slew``    slew to R = Rz(yaw) Ry(pitch) Rx(roll), body → inertial (:func:`hil.so3.euler_zyx`), within
            the scenario's rate and acceleration limits
==========  ==========================================================================================

Every step is an ``events.jsonl`` record ``{"kind": "command", "origin": ..., "id": n, "command": ...,
"status": ...}``: ``sent`` (to the board) then ``acked`` / ``nacked`` / ``failed`` (the board protocol's
answer), or ``applied`` / ``refused`` (host-side), each with details; and each command is in the run's
operator log (:class:`OperatorLog`, ``summary.json``'s ``operator``) with its last
status, so a run's record says what an operator did to it and when.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from hil import so3
from hil.runtime.observer import RunAborted
from hil.runtime.watch import STATE_CONFIRM_S
from protocol.errors import HilError
from protocol.messages import BoardState

if TYPE_CHECKING:
    from hil.runtime.host import Host
    from hil.runtime.runlog import EventLog
    from protocol.reliable import Command as BoardCommand

COMMANDS = ("arm", "disarm", "abort", "hold", "slew")
TARGET_RANGE_DEG = (180.0, 90.0, 180.0)
"""How far (degrees, either way) a ``slew``'s roll, pitch and yaw may go: every attitude once
(:func:`hil.so3.euler_zyx`). The ground station's parser holds a request to them
(:data:`hil.gcs.uplink.ANGLE_RANGE`), a fault campaign draws within them."""
ORIGINS = {"gcs": "the ground station", "campaign": "the fault campaign"}
"""Who sends commands, as an exit reason names them (another origin is named as it is)."""


def sender(origin: str) -> str:
    """``origin`` as the exit reason names it ("the ground station")."""
    return ORIGINS.get(origin, origin)


def unfit(command: OperatorCommand) -> str | None:
    """Why ``command`` cannot be carried out as given, or None: a name not among :data:`COMMANDS`, a
    ``slew`` without three finite angles within :data:`TARGET_RANGE_DEG` (degrees). Every sender's command
    passes here — not only the ground station's, whose parser refuses such a request: a campaign's or a
    script's slew to NaN° went on to the controller, and its NaN setpoint ended the run with ``error:
    ActuatorSetpoint.units[0].gimbal = nan is out of range``; one without a target or of an unknown name
    with a bare AssertionError."""
    if command.name not in COMMANDS:
        return f"not a command (one of {', '.join(COMMANDS)}): {command.name!r}"
    if command.name != "slew":
        return None
    target = command.target
    if target is None or len(target) != 3:
        return f"a slew needs its target (roll, pitch, yaw) in degrees, got {target!r}"
    for axis, angle, limit in zip(("roll", "pitch", "yaw"), target, TARGET_RANGE_DEG, strict=True):
        if not (isinstance(angle, (int, float)) and math.isfinite(angle) and abs(angle) <= limit):
            return f"slew {axis} must be a number of degrees within ±{limit:g}°, got {angle!r}"
    return None


@dataclass(frozen=True)
class OperatorCommand:
    """One command: ``id`` (unique within the run, per origin), ``name`` (one of :data:`COMMANDS`),
    ``target`` (roll, pitch, yaw) degrees for ``slew``, ``origin`` who sent it (``gcs``, ``campaign``, ...)
    and ``remote`` (the sender's address, where there is one)."""

    id: int
    name: str
    target: tuple[float, float, float] | None = None
    origin: str = "gcs"
    remote: str = ""


@dataclass
class _Pending:
    command: OperatorCommand
    handle: BoardCommand
    sent_t: float


class Operator:
    """Carries out :class:`OperatorCommand` s on the control thread (see the module docstring). Not
    thread-safe: call it from the run's control tick only."""

    def __init__(self) -> None:
        self._pending: list[_Pending] = []
        self._abort: _Pending | None = None

    @property
    def aborting(self) -> bool:
        return self._abort is not None

    def apply(self, host: Host, t: float, command: OperatorCommand) -> None:
        """Carry out ``command`` at ``t`` (s); its answer, for board commands, is settled by :meth:`service`
        on a later tick. Raises :class:`RunAborted` when an abort cannot reach the board."""
        if self._abort is not None:
            self._log(host, t, command, "refused", reason="the run is being aborted")
            return
        why = unfit(command)
        if why is not None:
            self._log(host, t, command, "refused", reason=why)
            return
        name = command.name
        if name in ("arm", "disarm", "abort"):
            try:  # through the host: its own re-arming yields to the operator's disarm
                if name == "arm":
                    handle = host.arm(t, command.origin)
                else:
                    handle = host.disarm(t, command.origin)
            except HilError as exc:
                self._log(host, t, command, "refused", reason=f"link: {exc}")
                if name == "abort":
                    raise RunAborted(
                        f"from {sender(command.origin)} (command {command.id}: the link is down; the board's "
                        "link watchdog fails it safe)"
                    ) from exc
                return
            pending = _Pending(command, handle, t)
            self._log(host, t, command, "sent", message="Arm" if name == "arm" else "Disarm")
            if name == "abort":
                self._abort = pending
            self._pending.append(pending)
            return
        if name == "hold":
            reason = host.retarget(t, None)
        else:
            assert command.target is not None
            reason = host.retarget(t, so3.euler_zyx(*command.target))
        if reason is not None:
            self._log(host, t, command, "refused", reason=reason)
            return
        assert host.slew is not None and host.target is not None
        self._log(
            host,
            t,
            command,
            "applied",
            target_r=so3.log(host.target).tolist(),
            slew_s=host.slew.duration_s,
            target_euler_deg=command.target,
        )

    def service(self, host: Host, t: float) -> None:
        """Settle the commands the board has answered; raises :class:`RunAborted` once an abort's Disarm is
        answered (or cannot be sent) and the board is seen disarmed."""
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
        go); at most :data:`~hil.runtime.watch.STATE_CONFIRM_S` after the ack. Only telemetry received
        since the ack, and live (younger than the host's ``stale_after_s``), is the board's word on the
        Disarm: a link that went silent just after the ack left the telemetry from before it, ARMED, and
        the exit said the board "still says ARMED 0.5 s later" — a board that had obeyed, said to disobey
        on a value half a second old."""
        n, origin = abort.command.id, sender(abort.command.origin)
        if not abort.handle.ok:
            raise RunAborted(
                f"from {origin} (command {n}: the Disarm failed; the board's link watchdog fails it safe)"
            )
        client = host.client
        tel, tel_t = client.latest_telemetry()  # one pair: a reader thread may take a frame between two reads
        settled = abort.handle.settled_at
        heard = tel is not None and tel_t is not None and settled is not None and tel_t >= settled
        if heard and tel is not None and tel.state is not BoardState.ARMED:
            raise RunAborted(f"from {origin} (command {n}: board disarmed, telemetry says {tel.state.name})")
        if settled is not None and t - settled < STATE_CONFIRM_S:
            return  # acknowledged; wait for the telemetry that shows it
        if tel is None or tel_t is None:
            raise RunAborted(f"from {origin} (command {n}: board disarmed, no telemetry to show it)")
        if heard and t - tel_t <= host.stale_after_s:  # live, since the ack: the run's way out disarms again
            raise RunAborted(
                f"from {origin} (command {n}: the board acknowledged the Disarm, yet its telemetry still "
                f"says ARMED {STATE_CONFIRM_S:g} s later)"
            )
        raise RunAborted(
            f"from {origin} (command {n}: the board acknowledged the Disarm, no live telemetry since to show "
            f"it: the last is {(t - tel_t) * 1e3:.0f} ms old)"
        )

    def _settle(self, host: Host, t: float, p: _Pending) -> None:
        """The board's answer, as the protocol settled it: acked, nacked (with its reason), superseded (a
        newer command set the same thing before an answer came: whether the board carried this one out is
        not known, its reason says so — "failed" read as "no answer from the board") or failed."""
        from protocol.reliable import CommandState

        handle = p.handle
        after_ms = (t - p.sent_t) * 1e3
        if handle.state is CommandState.ACKED:
            self._log(host, t, p.command, "acked", after_ms=after_ms, seq=handle.seq)
        elif handle.state is CommandState.NACKED:
            reason = None if handle.reason is None else handle.reason.name
            self._log(host, t, p.command, "nacked", reason=reason, after_ms=after_ms, seq=handle.seq)
        else:
            status = "failed" if handle.superseded_by is None else "superseded"
            self._log(host, t, p.command, status, reason=handle.failure, after_ms=after_ms, seq=handle.seq)

    @staticmethod
    def _log(host: Host, t: float, command: OperatorCommand, status: str, **fields: Any) -> None:
        host.record_command(t, command, status, **fields)


class OperatorLog:
    """The run's record of the operator's commands: each step of each command an ``events.jsonl`` record,
    and each command one entry in :attr:`entries` (``summary.json``'s ``operator``), created at its first
    step and updated with its last status."""

    def __init__(self, events: EventLog) -> None:
        self.events = events
        self.entries: list[dict[str, Any]] = []

    def record(self, t: float, command: OperatorCommand, status: str, **fields: Any) -> None:
        """``command``'s step at ``t`` (s): ``status`` (``sent``, ``acked``, ``refused``, ...) and its
        details ``fields`` (a ``reason`` is kept in the entry too)."""
        self.events.write(
            t,
            "command",
            origin=command.origin,
            id=command.id,
            command=command.name,
            status=status,
            remote=command.remote,
            **fields,
        )
        for entry in reversed(self.entries):
            if entry["id"] == command.id and entry["origin"] == command.origin:
                entry.update(status=status, status_t=t)
                if "reason" in fields:
                    entry["reason"] = fields["reason"]
                return
        entry = {
            "t": t,
            "id": command.id,
            "origin": command.origin,
            "command": command.name,
            "status": status,
            "status_t": t,
        }
        if command.target is not None:
            entry["target_euler_deg"] = list(command.target)
        if "reason" in fields:
            entry["reason"] = fields["reason"]
        self.entries.append(entry)


class ScheduledOperator:
    """A run observer (:class:`hil.runtime.observer.RunObserver`) that sends ``schedule``'s commands at
    their times (host clock s), through an :class:`Operator` — what a fault campaign's drawn operator does
    to a run, and what a test scripts. Commands due at the same tick go in the order given."""

    def __init__(self, schedule: list[tuple[float, OperatorCommand]]) -> None:
        self.schedule = sorted(schedule, key=lambda item: item[0])
        self.operator = Operator()
        self._next = 0
        self.host: Host | None = None

    def started(self, start: Any) -> None:
        self.host = start.host

    def row(self, row: Any) -> None:
        """Rows are not what this observer acts on."""

    def event(self, record: Any) -> None:
        """Nor events: it acts on the clock alone."""

    def tick(self, t: float) -> None:
        host = self.host
        if host is None:
            return
        while self._next < len(self.schedule) and self.schedule[self._next][0] <= t:
            self.operator.apply(host, t, self.schedule[self._next][1])
            self._next += 1
        self.operator.service(host, t)

    def finished(self, summary: Any) -> None:
        """The run's summary holds the operator log itself."""
