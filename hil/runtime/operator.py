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

A ``hold`` or ``slew`` takes effect only while the host steers the board (the slew or the hold phase,
the board in hand). While the operator has the run suspended (Disarm) or a recovery's warm-up is on, the
target is taken but its slew starts only when the warm-up ends: the command is ``deferred`` (with why),
then ``applied`` when its slew starts (``slew_start_s``), or ``superseded`` when a newer target replaced it
first; a run that ends before leaves it ``deferred``. Before, it was ``applied`` at once, its ``slew_s`` a
plan that never ran, while the host sent no setpoints. In the slew or the hold phase with the board not in
hand (no live telemetry, a re-arm pending, the board not armed, the phone not fresh) it is ``refused``:
the reference would move on with no setpoint going out.

An ``applied`` hold or slew whose board is not heard again (no telemetry made after the command) before the
host stops steering — a stall or a reset that began just before it, found only at the stale bound — never
reached the board: it is ``deferred`` then, with why, and ``applied`` again when its re-planned slew starts
at the recovery's end (``slew_start_s``). Before, its record said ``applied`` with a slew that never ran;
the re-plan was only in ``events.jsonl``'s ``resume``.

Once an ``abort``'s Disarm is out, every command after it is refused, whichever sender's
(:attr:`OperatorLog.aborting`: the ground station and a script or a campaign operate one run at once).

A command whose ``id`` its origin already used in this run is ``refused`` (its record's ``id`` null,
``duplicate_id`` the id): the operator log keys its steps by origin and id, and a script's second command
1 overwrote the first one's entry — a Disarm shown ``applied``, the slew never in the summary.

Every step is an ``events.jsonl`` record ``{"kind": "command", "origin": ..., "id": n, "command": ...,
"status": ...}``: ``sent`` (to the board) then ``acked`` / ``nacked`` / ``failed`` (the board protocol's
answer), or ``applied`` / ``refused`` (host-side), each with details; and each command is in the run's
operator log (:class:`OperatorLog`, ``summary.json``'s ``operator``) with its last
status, so a run's record says what an operator did to it and when.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from hil import so3
from hil.numbers import finite_number
from hil.runtime.observer import RunAborted
from hil.runtime.phases import Phase
from hil.runtime.watch import STATE_CONFIRM_S
from protocol.errors import HilError
from protocol.messages import BoardState

if TYPE_CHECKING:
    from numpy.typing import NDArray

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
        number = finite_number(angle)  # never a bool (True was a 1° slew), nor an int past a float's range
        if number is None or abs(number) > limit:
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


@dataclass
class _Unheard:
    """A hold or slew applied while the host steers, its board not heard since (no telemetry made after
    ``t``): whether its slew reached the board is not known yet."""

    command: OperatorCommand
    target: NDArray[Any]
    t: float  # applied at (host s)


@dataclass
class _Deferred:
    """A hold or slew taken while the host does not steer: its target (the host's target array, taken as
    it was set: another target replaces the object) waits for the warm-up's end."""

    command: OperatorCommand
    target: NDArray[Any]
    t: float  # taken at (host s)


STEERING = (Phase.SLEW, Phase.HOLD)
"""The phases in which the host steers the board on its reference: a new target takes effect at once."""
NOT_IN_HAND = (
    "the host does not have the board in hand (no live telemetry, a re-arm pending, the board not armed "
    "or the phone not fresh): a new target would move the reference on with no setpoint going out"
)


class Operator:
    """Carries out :class:`OperatorCommand` s on the control thread (see the module docstring). Not
    thread-safe: call it from the run's control tick only."""

    def __init__(self) -> None:
        self._pending: list[_Pending] = []
        self._deferred: list[_Deferred] = []
        self._unheard: list[_Unheard] = []
        self._abort: _Pending | None = None

    @property
    def aborting(self) -> bool:
        return self._abort is not None

    def apply(self, host: Host, t: float, command: OperatorCommand) -> None:
        """Carry out ``command`` at ``t`` (s); its answer, for board commands, is settled by :meth:`service`
        on a later tick. Raises :class:`RunAborted` when an abort cannot reach the board. A command id its
        origin already used in the run is refused (:meth:`OperatorLog.refuse_duplicate`)."""
        if host.operator.used(command):
            host.operator.refuse_duplicate(t, command)
            return
        aborting = host.operator.aborting
        if aborting is not None:
            reason = f"the run is being aborted (command {aborting.id} from {sender(aborting.origin)})"
            self._log(host, t, command, "refused", reason=reason)
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
                host.operator.aborting = command
            self._pending.append(pending)
            return
        self._retarget(host, t, command)

    def _retarget(self, host: Host, t: float, command: OperatorCommand) -> None:
        """A ``hold`` or ``slew`` at ``t`` (s): applied at once while the host steers the board, deferred
        to the warm-up's end while the run is suspended or recovering, refused when it cannot take effect
        (see the module docstring)."""
        self._settle_deferred(host, t)  # a slew that started since the last tick is applied, not superseded
        if host.phase in STEERING and not host.in_control:
            self._log(host, t, command, "refused", reason=NOT_IN_HAND)
            return
        if command.name == "hold":
            reason = host.retarget(t, None)
        else:
            assert command.target is not None
            reason = host.retarget(t, so3.euler_zyx(*command.target))
        if reason is not None:
            self._log(host, t, command, "refused", reason=reason)
            return
        assert host.target is not None
        if host.phase in STEERING:
            self._applied(host, t, command)
            self._unheard.append(_Unheard(command, host.target, t))
            return
        why = (
            "the run is suspended by the operator's Disarm: the slew to this target starts after the "
            "operator's Arm and the warm-up"
            if host.phase is Phase.SUSPENDED
            else "a recovery's warm-up is on (the host is not steering): the slew to this target starts "
            "when it ends"
        )
        self._log(host, t, command, "deferred", reason=why, target_euler_deg=command.target)
        self._deferred.append(_Deferred(command, host.target, t))

    def _applied(self, host: Host, t: float, command: OperatorCommand, **fields: Any) -> None:
        """``command``'s target is what the host steers to from now on: its record with the slew planned."""
        assert host.slew is not None and host.target is not None
        self._log(
            host,
            t,
            command,
            "applied",
            target_r=so3.log(host.target).tolist(),
            slew_s=host.slew.duration_s,
            target_euler_deg=command.target,
            **fields,
        )

    def _settle_deferred(self, host: Host, t: float) -> None:
        """Each deferred command at ``t`` (s): ``superseded`` once another target (from any sender)
        replaced its own, ``applied`` once the host steers to it again (its slew planned at the warm-up's
        end, ``slew_start_s``)."""
        still = []
        for d in self._deferred:
            if host.target is not d.target:
                self._log(
                    host,
                    t,
                    d.command,
                    "superseded",
                    reason="a newer target replaced it before its slew started",
                )
            elif host.phase in STEERING:
                assert host.slew is not None
                self._applied(host, t, d.command, slew_start_s=host.slew.start_s, deferred_s=t - d.t)
            else:
                still.append(d)
        self._deferred = still

    def _settle_unheard(self, host: Host, t: float) -> None:
        """Each applied command at ``t`` (s) whose board was not heard since: kept ``applied`` once
        telemetry made after it comes while the host still has the board in hand (the board lived on under
        its setpoints), or once a newer target replaced it; ``deferred`` once the host stops steering first
        (a stall or reset that began before the command, found since): its slew never ran, the recovery
        re-plans it (:meth:`_settle_deferred` then records it ``applied`` with its ``slew_start_s``). The
        board's first telemetry after a stall comes in the tick that ends the steering (it says FAILSAFE):
        telemetry counts only while the host steers with the board in hand."""
        if not self._unheard:
            return
        _, tel_t = host.client.latest_telemetry()
        steering = host.phase in STEERING
        heard = steering and host.in_control and tel_t is not None
        still = []
        for u in self._unheard:
            if (heard and tel_t is not None and tel_t > u.t) or host.target is not u.target:
                continue
            if steering:
                still.append(u)
                continue
            self._log(
                host,
                t,
                u.command,
                "deferred",
                reason="the board was not heard steering after the command (a stall or a reset that began "
                "before it, found since): its slew never ran; the slew to this target starts when the "
                "recovery's warm-up ends",
                target_euler_deg=u.command.target,
            )
            self._deferred.append(_Deferred(u.command, u.target, u.t))
        self._unheard = still

    def service(self, host: Host, t: float) -> None:
        """Settle the commands the board has answered; raises :class:`RunAborted` once an abort's Disarm is
        answered (or cannot be sent) and the board is seen disarmed. Deferred holds and slews are applied
        once their slew starts (or superseded)."""
        self._settle_unheard(host, t)
        self._settle_deferred(host, t)
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
        self.aborting: OperatorCommand | None = None
        """The abort whose Disarm is out, from whichever :class:`Operator` (the run's, shared by all of
        them): every command after it is refused. Each operator once knew its own abort only: a script's
        Arm in the same tick as a campaign's abort went out, superseded the abort's Disarm and re-armed the
        board, and the run's exit said "the Disarm failed; the board's link watchdog fails it safe"."""

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
        entry = self._entry(command)
        if entry is not None:
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

    def _entry(self, command: OperatorCommand) -> dict[str, Any] | None:
        """The entry of ``command``'s origin and id (a refused duplicate's own entry is never it)."""
        for entry in reversed(self.entries):
            if entry["id"] == command.id and entry["origin"] == command.origin and not entry.get("duplicate"):
                return entry
        return None

    def used(self, command: OperatorCommand) -> bool:
        """Whether ``command``'s origin already sent a command of its id in this run."""
        return self._entry(command) is not None

    def refuse_duplicate(self, t: float, command: OperatorCommand) -> None:
        """``command`` reuses an id its origin already used: refused at ``t`` (s), in a record and an entry
        of its own — its ``events.jsonl`` record's ``id`` null (a ground station's page keys a command's
        steps by origin and id: it would have shown the first command refused), ``duplicate_id`` the id;
        its entry marked ``duplicate`` — so that the first command's steps and entry stay its own."""
        first = self._entry(command)
        assert first is not None
        reason = f"duplicate id: {command.origin!r} already sent command {command.id} ({first['command']!r})"
        self.events.write(
            t,
            "command",
            origin=command.origin,
            id=None,
            duplicate_id=command.id,
            command=command.name,
            status="refused",
            remote=command.remote,
            reason=reason,
        )
        entry = {
            "t": t,
            "id": command.id,
            "origin": command.origin,
            "command": command.name,
            "status": "refused",
            "status_t": t,
            "reason": reason,
            "duplicate": True,
        }
        if command.target is not None:
            entry["target_euler_deg"] = list(command.target)
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
