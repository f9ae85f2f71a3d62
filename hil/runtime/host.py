"""The host's closed loop for one run: phone samples → merge → estimator, and at the control rate
estimate → controller → steering → setpoints for the board. No clock or thread of its own:
:mod:`hil.runtime.loop` calls :meth:`Host.feed` from the estimator task and :meth:`Host.tick` from the
control task, in real time or in lockstep.

:class:`Host` is the coordinator; each job is its own module:

=================================  ========================================================================
:mod:`hil.runtime.phone_clock`     the phone's clock: admission, dropped readings, re-anchorings, gaps
:mod:`hil.runtime.phone_senders`   other phones on the phone's port: the receiver's moments as events
:mod:`hil.runtime.phases`          the run's phases (warm-up, slew, hold, recovery, the operator's
                                   suspension) as a state machine with named transitions
:mod:`hil.runtime.control_step`    controller → steering → setpoints, and the hold and rest setpoints
:mod:`hil.runtime.watch`           the board's events, the host's view of it, re-arming
:mod:`hil.runtime.actuators`       whether the actuators follow what they are told
:mod:`hil.runtime.rows`            each tick's record from a :class:`~hil.runtime.rows.TickSnapshot`
:mod:`hil.runtime.summary`         the run's summary and its requirement verdict
:mod:`hil.runtime.operator`        the operator's commands and their log
=================================  ========================================================================

**Faults** (:mod:`hil.runtime.watch`, :mod:`hil.runtime.faults`). The host's view of the board has an age:
while no telemetry comes for ``stale_after_s`` (or the link is lost) the host stops commanding the board —
one hold setpoint (gimbals still, rotors at nominal speed) when it loses sight of it, nothing more — and
its telemetry rows carry no board value, only how old the last telemetry is and why. A board that fails
safe, resets, reconnects or is disarmed is re-armed through the protocol (not when the operator disarmed
it) and the host **re-enters its warm-up** (:meth:`hil.runtime.phases.RunPhases.restart_warmup`) before
it steers again: the rotors back at speed and every check passed (telemetry live, the board armed, the
phone fresh), then a new slew from the attitude estimated then to the target. A phone gap (no sample for
``stale_after_s``) or a phone that restarted its clock (the estimator starts afresh) holds the gimbals
too, and its warm-up includes the still window. Every fault is in the run's fault journal; an outage
longer than ``recover_within_s`` ends the run as lost (:attr:`Host.lost`).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from hil.bounded_estimator import with_bounded_calls
from hil.control.attitude import EigenaxisSlew, Reference
from hil.estimation.admission import PhoneGuard, Verdict
from hil.estimation.interface import Estimator
from hil.estimation.sensors import SensorKind, SensorSample
from hil.link.board import BoardClient
from hil.link.board.events import StateEvent
from hil.runtime.actuators import ActuatorWatch
from hil.runtime.control_step import ControlStep, Steered
from hil.runtime.faults import RECOVER_WITHIN_S, STALE_AFTER_S, FaultJournal
from hil.runtime.operator import OperatorCommand, OperatorLog
from hil.runtime.phases import Phase, RunPhases
from hil.runtime.phone_clock import MAX_GAP_S, Freshness, PhoneClock
from hil.runtime.phone_senders import SenderWatch
from hil.runtime.rows import BoardReading, TickRecorder, TickSnapshot
from hil.runtime.runlog import CsvLog, EventLog, RowTap
from hil.runtime.summary import HostCounters, run_summary
from hil.runtime.telemetry import RunTrace, TelemetrySchema
from hil.runtime.watch import BoardWatch, View
from hil.scenario import Scenario
from protocol.errors import BoardReset
from protocol.messages import ActuatorSetpoint, BoardState
from protocol.reliable import Command

if TYPE_CHECKING:
    from hil.estimation.estimator import Estimate
    from hil.estimation.multirate import MergeStats

logger = logging.getLogger(__name__)

Array = NDArray[np.float64]

__all__ = ["Host", "HostCounters", "Phase", "TruthSample"]


def _time_order(sample: SensorSample) -> tuple[bool, float]:
    """Sort key: by time stamp, the stamps that are not numbers last (the guard drops them)."""
    t = sample.t_s
    return (True, 0.0) if not math.isfinite(t) else (False, t)


@dataclass(frozen=True)
class TruthSample:
    """What a simulation knows and a real board does not: attitude ``R`` (3, 3), body rate (3,) rad/s."""

    R: Array
    omega: Array


@dataclass
class Host:
    """One run's host side. ``truth`` (optional) returns the simulation's truth now (None on hardware);
    ``telemetry`` None keeps no telemetry rows (a Monte Carlo run: its figures come from :attr:`trace`);
    ``stale_after_s``: board telemetry and phone samples older than this are not live;
    ``recover_within_s``: an outage (or phone gap) longer than this loses the run (:attr:`lost`)."""

    scenario: Scenario
    client: BoardClient
    telemetry: CsvLog | RowTap | None
    events: EventLog
    truth: Callable[[], TruthSample | None] = lambda: None
    duration_s: float | None = None
    make_estimator: Callable[[], Estimator] | None = None  # a fresh estimator (default: the scenario's)
    hold: bool = False  # target the attitude estimated at the end of the warm-up, not the scenario's
    stale_after_s: float = STALE_AFTER_S
    recover_within_s: float = RECOVER_WITHIN_S
    counters: HostCounters = field(default_factory=HostCounters)

    def __post_init__(self) -> None:
        from hil.estimation.multirate import Merger, MergeStats

        sc = self.scenario
        self.n = sc.spacecraft.n_units
        self._make_estimator = self.make_estimator or sc.make_estimator
        self.filter: Estimator = self._new_filter()
        self.merger = Merger()
        self._retired_merges = MergeStats()  # the counts of the mergers a fresh start replaced
        self.estimate: Estimate | None = None
        self.control = ControlStep(sc)
        self.finished = False
        self.lost: str | None = None  # why the run lost the board (or the phone), if it did
        self.ended_at: float | None = None  # host time (s) the run's loop ended (None: not yet)
        self.last_view: View | None = None  # the board as the last control tick saw it (the run's end)
        self.journal = FaultJournal(self.recover_within_s)
        self.watch = BoardWatch(self.client, self.events, self.journal, self.stale_after_s)
        self.phases = RunPhases(sc, self.events, self.journal, self.hold)
        self.phone = PhoneClock(self.journal, self.events, self.stale_after_s)
        self.senders = SenderWatch(self.events)
        self.in_control = True
        self._unsteered_since: float | None = None  # host s the current run of no-command ticks began
        self._hold_sent = False  # the hold setpoint went out since the board was last seen
        self._hold_tick = -1  # the control tick it went out in
        self.actuators = ActuatorWatch(
            self.n,
            self.journal,
            self.events,
            self.control.setpoints.max_lead,
            self.control.setpoints.params.limits.max_rotor_speed,
        )
        self.trace = RunTrace()
        self.schema = TelemetrySchema(self.n)
        self.columns = list(self.schema.columns)
        self.operator = OperatorLog(self.events)
        self.rows = TickRecorder(self.schema, self.telemetry, self.trace)

    def _new_filter(self) -> Estimator:
        """A fresh estimator, the scenario's choice (or the caller's ``make_estimator``): the one place the
        host makes one (at the start, and afresh whenever the phone's stream is not to be integrated
        across). A user's is held to a bounded wait on its live calls (:func:`with_bounded_calls`)."""
        return with_bounded_calls(self._make_estimator())

    # ------------------------------------------------------------------ what the run's users read
    @property
    def phase(self) -> Phase:
        return self.phases.phase

    @property
    def target(self) -> Array | None:
        """The target attitude (3, 3) body → inertial (None before it is known: ``hold`` runs)."""
        return self.phases.target

    @property
    def slew(self) -> EigenaxisSlew | None:
        """The slew the reference follows (None before the first)."""
        return self.phases.slew

    @property
    def suspended_since(self) -> float | None:
        """When the operator's Disarm suspended the run (host s), None unless suspended."""
        return self.phases.suspended_since

    @property
    def time_limit_extension_s(self) -> float:
        """How far the operator's suspensions (closed ones) move the run's time limit (s)."""
        return self.phases.suspended_s

    @property
    def guard(self) -> PhoneGuard:
        """The phone's admission policy and clock guard."""
        return self.phone.guard

    @property
    def merge_stats(self) -> MergeStats:
        """The merge's counts over the whole run (every merger's: a fresh start makes a new one) — what
        the merger dropped after the admission let it through, by sensor and reason, among them."""
        from hil.estimation.multirate import MergeStats

        total = MergeStats(driver=self.merger.driver, failover_order=self.merger.failover_order)
        total.absorb(self._retired_merges)
        total.absorb(self.merger.stats)
        return total

    def end(self, t: float) -> None:
        """The run's loop has ended at ``t`` (s): the instant its summary measures open outages, gaps and
        suspensions at — not when the summary is written, after the way out's Disarm waited for its
        answer (an exit said "lost … for 0.2 s" beside a summary's 0.7 s). The drops the record's rate
        limits held back go in; faults heard from now on are the record's (:meth:`FaultJournal.end`),
        not outages of the run."""
        self.ended_at = t
        self.phone.note_held_drops(t, final=True)
        self.journal.end(t)

    def heard_on_the_way_out(self, events: Sequence[Any]) -> None:
        """The board's ``events`` heard after the loop (its final Disarm: a reset found there was counted
        nowhere), into the record — not its changes of state, but for a FAILSAFE: the way out's own
        Disarm made the others, which the watch, holding the board armed, would take for a Disarm no one
        meant. A FAILSAFE is the board's own (its link watchdog: nothing of the host's reached it for its
        link timeout, since before the loop ended); dropped with the rest, a board that failed safe just
        after the last tick left no failsafe in events.jsonl or the summary, and the run said
        ``completed`` (:meth:`FaultJournal.lost_after_the_run` now names it)."""
        self.watch.on_events(
            [e for e in events if not isinstance(e, StateEvent) or e.new is BoardState.FAILSAFE]
        )

    @property
    def accepted_by_sensor(self) -> dict[str, int]:
        """Each sensor's samples the merge accepted over the whole run (by ``SensorKind.label``): every
        merger's, so a count that never goes back — a fresh start makes a new merger, whose own counts
        start at zero."""
        accepted = self.merger.stats.accepted
        retired = self._retired_merges.accepted
        return {label: n + retired.get(label, 0) for label, n in accepted.items()}

    @property
    def operator_log(self) -> list[dict[str, Any]]:
        """Each operator command, its last status (the summary's ``operator``)."""
        return self.operator.entries

    # ------------------------------------------------------------------ estimator task
    def feed(self, samples: Sequence[SensorSample], now: float | None = None) -> None:
        """Phone samples (any order within a batch) through the admission policy and clock guard
        (:class:`hil.runtime.phone_clock.PhoneClock`: absurd, spoofed and flooding readings dropped and
        counted; a stream whose clock really moved re-anchored) and hold-last-sample merging into the
        estimator; ``now``: the host's time (s), for the record."""
        phases = self.phases
        collecting = phases.collecting_bias
        phone = self.phone
        for sample in sorted(samples, key=_time_order):
            self.counters.samples += 1
            verdict, advance_s = phone.admit(sample, now)
            if verdict is Verdict.DROP:
                continue
            if verdict is not Verdict.ACCEPT:
                self._phone_reanchored(verdict, sample.t_s, now)
            elif advance_s > MAX_GAP_S and self.estimate is not None:
                self._restart_estimator()  # a stream that paused: not integrated across
                t = now if now is not None else sample.t_s
                self.events.write(t, "estimator_restart", gap_s=advance_s)
            if collecting and sample.kind is SensorKind.GYR:
                phases.add_bias_sample(np.asarray(sample.xyz, dtype=float))
            for step in self.merger.push(sample):
                self.estimate = self.filter.step(step)
                self.counters.estimator_steps += 1

    def _restart_estimator(self) -> None:
        """The merger and the estimator afresh, from the next measurements (the gyro bias measured so far
        kept): after a stream's clock moved, or a pause longer than :data:`MAX_GAP_S` — integrating the
        held gyro across it would be a guess, and its cost grows with the gap (sub-steps)."""
        from hil.estimation.multirate import Merger

        self._retired_merges.absorb(self.merger.stats)
        self.merger = Merger(self.merger.policy)
        self.filter = self._new_filter()
        self.filter.set_gyro_bias(self.phases.gyro_bias)
        self.filter.set_rest_learning(self.phases.first_warmup)
        self.estimate = None

    def _phone_reanchored(self, verdict: Verdict, t_s: float, now: float | None) -> None:
        """The phone stream's clock moved (restarted or jumped forward). Integrating across the jump
        would be wrong either way: the merger and the estimator start afresh from the measurements (the
        gyro bias is kept), and the warm-up's still window lets the estimate converge before the host
        steers again. (A stray first reading the guard anchored on reached the merger too: the same
        fresh start, but no clock moved, so no restart is counted.)"""
        if verdict is not Verdict.STRAY:
            self.counters.phone_restarts += 1
        self._restart_estimator()
        t, kind = self.phone.reanchored(verdict, t_s, now)
        self.phases.restart_warmup(t, kind, still=True)

    # ------------------------------------------------------------------ control task
    def tick(self, t: float, events: Sequence[Any], due: float | None = None) -> None:
        """One control period at host time ``t`` (s), after the board client's new ``events``; ``due`` its
        deadline (None: on time), which a tick more than ``stale_after_s`` late journals as the host's own
        stall (:meth:`BoardWatch.host_stalled`) — first, so the outage starts at the missed deadline."""
        self.counters.control_ticks += 1
        watch = self.watch
        if due is not None and watch.host_stalled(t, due):
            self._lose_if_overdue(t)  # before the board is seen back: a stall beyond the bound is a loss
        watch.on_events(events)
        for why in watch.take_upsets():
            self.phases.restart_warmup(t, why, still=False)
        phone_fresh = self._phone_fresh(t)
        self.phone.note_held_drops(t)
        view = self.last_view = watch.view(t)
        watch.hold_disarmed(t, view)
        watch.hold_armed(t, view)
        # no re-arm is started on the run's last tick (its time up, or lost: a host stalled beyond the
        # bound): the board would be left ARMED, commanded by no one
        watch.rearm_if_needed(t, start=not (self.finished or self.phases.time_is_up(t, self._duration)))
        self.in_control = watch.in_control(t, view, phone_fresh)
        self._lose_if_overdue(t)
        tel = view.telemetry
        if tel is None or len(tel.units) != self.n:
            self._hold_if_blind()
            hold = self._blind_hold() if self._hold_tick == self.counters.control_ticks else None
            self.rows.record(self._snapshot(t, view, None, None, hold, None))
            # the run's time is up whether or not the board is in view: one that ends blind ends with
            # its outage still on, and says so (it ran on past its end to the next live tick, completed)
            if self.phases.time_is_up(t, self._duration):
                self.finished = True
            return
        self._hold_sent = False
        self.actuators.board_flags(t, tel.faults, tel.power)
        units = tel.units
        gimbal = [u.gimbal_angle for u in units]  # floats: the tick computes on floats (rad, rad/s)
        rotor = [u.rotor_speed for u in units]
        self.actuators.rotor_speeds(t, rotor)
        armed = tel.state is BoardState.ARMED
        command, steered, ref = self._control(t, gimbal, rotor, armed, phone_fresh)
        if steered is not None:
            self._note_unsteered(t, steered)
        if armed and not watch.rearm_pending and command is not None:
            self._send(command)
            if steered is not None:  # the steering's: what the actuators should follow
                self.actuators.following(t, rotor, units, command)
        board = BoardReading(tel, gimbal, rotor)
        self.rows.record(self._snapshot(t, view, ref, board, command, steered))
        if self.phases.time_is_up(t, self._duration):
            self.finished = True

    def _estimated_attitude(self) -> Array | None:
        """The attitude estimated now (3, 3), body → inertial, to plan a slew from; None while there is
        no estimate or it is not finite (an estimator that lost itself for a moment, say). A slew planned
        from a NaN attitude is NaN at every reference point: the run steered with nothing to its end,
        though the estimate came back a tick later (a warm-up that ended then began the scenario's slew
        from it). None makes the warm-up wait, and a retarget refused, until an estimate is usable."""
        est = self.estimate
        if est is None:
            return None
        R = est.R
        return R if bool(np.isfinite(R).all()) else None

    def _note_unsteered(self, t: float, steered: Steered) -> None:
        """Count a control tick at ``t`` (s) on which steering had no finite command to give
        (:attr:`hil.control.steering.Saturation.NOT_FINITE`: the array was given none — gimbals still,
        rotor accelerations 0 — so the run steered with nothing, which its rows alone did not say), and
        log each episode of them once: an ``unsteered`` event (and a warning) at its first tick, a
        ``steered_again`` event with its length (s) at the first tick steering gives a command again.

        The torque the controller asked for is the input tested: the gimbal angles and rotor speeds come
        from the board's telemetry, bounded by the wire (:mod:`protocol.messages`), so a demand that is
        not a number (a NaN or infinite estimate, say) is how a tick has no finite command here."""
        if all(map(math.isfinite, steered.torque)):
            if self._unsteered_since is not None:
                self.events.write(t, "steered_again", after_s=t - self._unsteered_since)
                self._unsteered_since = None
            return
        self.counters.unsteered_ticks += 1
        if self._unsteered_since is None:
            self._unsteered_since = t
            self.counters.unsteered_episodes += 1
            self.events.write(t, "unsteered", why="the controller's torque demand is not a number")
            logger.warning("t=%.3f s: steering has no finite command (the torque demand is not a number)", t)

    def _lose_if_overdue(self, t: float) -> None:
        """The run has lost the board (or the phone) at ``t`` if an outage outlasted its bound: said once,
        and the run ends after this tick."""
        lost = self.journal.overdue(t)
        if lost is not None and self.lost is None:
            self.lost = lost
            self.finished = True
            self.events.write(t, "lost", why=lost)
            logger.error("%s", lost)

    def _snapshot(
        self,
        t: float,
        view: View,
        reference: Reference | None,
        board: BoardReading | None,
        command: ActuatorSetpoint | None,
        steered: Steered | None,
    ) -> TickSnapshot:
        """What this tick saw and did, for its record (the simulation's truth taken now)."""
        truth = self.truth()
        est = self.estimate
        phases = self.phases
        delta: float | None = None
        if board is not None:  # steering computed δ from this telemetry already, when it ran
            delta = self.control.delta(board.gimbal, board.rotor) if steered is None else steered.delta
        attitude, rate = (None, None) if est is None else est.floats()
        return TickSnapshot(
            t=t,
            phase=phases.phase,
            attitude=attitude,
            rate=rate,
            true_attitude=None if truth is None else truth.R,
            true_rate=None if truth is None else truth.omega,
            target9=phases.target9,
            slew_start=phases.slew_start,
            reference=reference,
            view=view,
            phone_heard=self.phone.heard,
            phone_samples=self.phone.count,
            board=board,
            command=command,
            torque=None if steered is None else steered.torque,
            delta=delta,
        )

    def _send(self, command: ActuatorSetpoint) -> None:
        try:
            self.client.send_setpoint(command)
        except BoardReset:  # the reset event arrives with the next service(); re-armed then
            self.counters.setpoint_errors += 1

    def _hold_if_blind(self) -> None:
        """The host cannot see the board: it stops commanding it. One hold setpoint (:meth:`_blind_hold`)
        goes out when it loses sight of it, if the link carries it, so that a board that still hears the
        host does not carry on with a command made from what is now stale."""
        if self._hold_sent or not self.client.connected or self.watch.rearm_pending:
            return
        self._hold_sent = True
        self._hold_tick = self.counters.control_ticks
        self._send(self._blind_hold())

    def _blind_hold(self) -> ActuatorSetpoint:
        """What the host holds the board at while it cannot see it: gimbals still, the rotors at rest
        during the first warm-up's still window (before its spin-up: the window measures the gyro bias
        with the rotors stopped), else at nominal speed. (The first tick, before any telemetry, sent the
        nominal speed: an armed board's rotors were kicked to ~20 rad/s inside the rest window.)"""
        return self.control.rest if self.phases.resting else self.control.hold

    def _phone_fresh(self, t: float) -> bool:
        """Whether the phone's samples are fresh at ``t`` (:meth:`PhoneClock.freshness`); a gap is a
        fault, and the warm-up (with its still window) follows it. Fresh takes the gyroscope's and the
        accelerometer's samples, each (the run's counts, over every merger: a fresh start makes a new one)."""
        by_kind = self.accepted_by_sensor
        freshness = self.phone.freshness(t, sum(by_kind.values()), by_kind)
        if freshness is Freshness.GAP_BEGAN:
            self.phases.restart_warmup(t, "phone_gap", still=True)
        return freshness is Freshness.FRESH

    @property
    def _duration(self) -> float:
        return self.scenario.slew.duration_s if self.duration_s is None else self.duration_s

    def _control(
        self, t: float, gimbal: list[float], rotor: list[float], armed: bool, phone_fresh: bool
    ) -> tuple[ActuatorSetpoint | None, Steered | None, Reference | None]:
        """The tick's command for the board with its gimbals at ``gimbal`` (n floats, rad) and rotors at
        ``rotor`` (n floats, rad/s): none while the operator has the run suspended, the rest or hold
        setpoint during the warm-up (which may end here, with a new slew), else the control step's on the
        slew's reference.
        Returns the command, the control step's result and the reference (None where it did not run)."""
        phases = self.phases
        if phases.phase is Phase.SUSPENDED:
            return None, None, None  # the operator disarmed the board: nothing to command
        if phases.phase is Phase.WARMUP:
            rotors = np.array(rotor)
            began = phases.warm_up(
                t,
                rotors,
                ready=armed and not self.watch.rearm_pending,
                # a phone that has not streamed yet is not late (no gap), but no still window starts on
                # it: the window would end with a fraction of its samples (a phone that started late)
                phone_fresh=phone_fresh and self.phone.heard is not None,
                attitude=self._estimated_attitude(),
                estimator=self.filter,
                esc_dead=self.actuators.esc_dead,
            )
            if began:
                self.control.reset(rotors)
            if phases.phase is Phase.WARMUP:
                return (self.control.rest if phases.resting else self.control.hold), None, None
        assert phases.slew is not None and self.estimate is not None
        phases.finish_slew(t)
        ref = phases.slew.at(t)
        R_hat, w_hat = self.estimate.floats()
        steered = self.control.step(R_hat, w_hat, ref, gimbal, rotor)
        return steered.setpoint, steered, ref

    # ------------------------------------------------------------------ from outside the loop
    def retarget(self, t: float, R_target: Array | None = None) -> str | None:
        """A new target from outside the loop (the ground station's slew or hold): an eigenaxis slew from
        the attitude estimated now to ``R_target`` (3, 3), body → inertial (None: hold the attitude
        estimated now), from ``t`` (s); why it was refused, or None
        (:meth:`hil.runtime.phases.RunPhases.retarget`)."""
        return self.phases.retarget(t, self._estimated_attitude(), R_target)

    def arm(self, t: float, origin: str = "gcs") -> Command:
        """The operator's Arm (sent now): the host re-arms on its own again after later faults. After the
        operator's Disarm it ends the suspension (:meth:`hil.runtime.phases.RunPhases.end_suspension`)."""
        cmd = self.watch.operator_arm(t)
        self.phases.end_suspension(t, origin)
        return cmd

    def disarm(self, t: float, origin: str = "gcs") -> Command:
        """The operator's Disarm (sent now): a re-arm the host had pending is cancelled and the run is
        *suspended* (:meth:`hil.runtime.phases.RunPhases.suspend`) — no re-arming on the host's own account
        — until :meth:`arm`. A run that ends suspended did not complete (``hil.runtime.loop``)."""
        self.phases.suspend(t, origin)
        # Without a session the Disarm cannot go out (LinkError, the operator's record says so), yet the
        # run stays suspended and the host never re-arms: the board, failed safe for want of the link,
        # comes back disarmed from its next handshake.
        return self.watch.operator_disarm(t)

    def record_command(self, t: float, command: OperatorCommand, status: str, **fields: Any) -> None:
        """An operator command's step (:mod:`hil.runtime.operator`) into the run's operator log."""
        self.operator.record(t, command, status, **fields)

    # ------------------------------------------------------------------ summary
    def summary(self) -> dict[str, Any]:
        """The run's figures, faults, operator commands and requirement verdict
        (:func:`hil.runtime.summary.run_summary`)."""
        return run_summary(
            now=self.ended_at if self.ended_at is not None else self.client.clock.now(),
            scenario=self.scenario,
            client=self.client,
            watch=self.watch,
            journal=self.journal,
            phases=self.phases,
            counters=self.counters,
            trace=self.trace,
            estimator_rmse=self.rows.estimator_rmse(),
            phone_admission=self.guard.as_dict(),
            phone_merge=self.merge_stats.as_dict(),
            operator_log=self.operator_log,
            lost=self.lost,
        )
