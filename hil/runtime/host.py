"""The host's closed loop for one run: phone samples → merge → estimator, and at the control rate
estimate → controller → steering → setpoints for the board, with the run's phases, its telemetry rows and
its summary. No clock or thread of its own: :mod:`hil.runtime.loop` calls :meth:`Host.feed` from the
estimator task and :meth:`Host.tick` from the control task, in real time or in lockstep.

Phases (``telemetry.csv`` column ``phase``):

0. **warm-up** — the board is armed; with the rotors still at rest the still window of ``warmup_s`` runs:
   the estimator converges and the raw gyroscope samples of the window's second half are averaged into
   the gyro bias, the estimator's bias estimate (the tuned estimator, learning it from rest detection in
   the window, refines it online in motion); then the rotors spin up with the gimbals still, and the slew
   starts ``ROTOR_SETTLE_S`` after every rotor is within 5 % of its nominal speed (the phone gyro's
   residual bias would otherwise leave a steady attitude error and a rate offset in the control loop);
1. **slew** — an eigenaxis rest-to-rest slew from the estimated attitude to the scenario's target within
   its rate and acceleration limits, tracked by the geometric controller;
2. **hold** — the reference stays at the target.

With ``hold=True`` (``hil replay --port``: a recorded phone's motion, which the actuators cannot change)
the target is the attitude estimated at the end of the warm-up: the controller then commands what it
takes to hold that attitude against the recorded motion.

The run ends ``duration_s`` after the slew started.

**Faults** (:mod:`hil.runtime.watch`, :mod:`hil.runtime.faults`). The host's view of the board has an age:
while no telemetry comes for ``stale_after_s`` (or the link is lost) the host stops commanding the board —
one hold setpoint (gimbals still, rotors at nominal speed) when it loses sight of it, nothing more — and
its telemetry rows carry no board value, only how old the last telemetry is and why. A board that fails
safe, resets, reconnects or is disarmed is re-armed through the protocol (not when the operator disarmed
it) and the host **re-enters its warm-up** before it steers again: the rotors back at speed and every check
passed (telemetry live, the board armed, the phone fresh), then a new slew from the attitude estimated
then to the target. (The rotors of a reset board are stopped: steering them gives no gimbal authority.) A
phone gap (no sample for ``stale_after_s``) or a phone that restarted its clock (the estimator starts
afresh) holds the gimbals too, and its warm-up includes the still window (the gyro bias measured in the
first one is kept). Every fault is in the run's fault journal; an outage longer than ``recover_within_s``
ends the run as lost (:attr:`Host.lost`).
"""

from __future__ import annotations

import enum
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil import so3
from hil.control.attitude import AttitudeController, EigenaxisSlew, Reference
from hil.control.motor_loops import SetpointGenerator
from hil.control.steering import VscmgSteering
from hil.estimation.admission import PhoneGuard, Verdict
from hil.estimation.interface import Estimator
from hil.estimation.sensors import SensorKind, SensorSample
from hil.link.board import BoardClient
from hil.runtime.actuators import ActuatorWatch
from hil.runtime.faults import RECOVER_WITHIN_S, STALE_AFTER_S, FaultJournal
from hil.runtime.rows import TickRecorder
from hil.runtime.runlog import CsvLog, EventLog, RowTap
from hil.runtime.telemetry import RunTrace, telemetry_columns
from hil.runtime.watch import BoardWatch
from hil.scenario import Scenario
from protocol.errors import BoardReset, HilError
from protocol.messages import ActuatorSetpoint, BoardState, GimbalMode, UnitSetpoint
from protocol.reliable import Command

logger = logging.getLogger(__name__)

Array = NDArray[np.float64]

SPUN_UP = 0.05  # rotors within this fraction of nominal: the still window may start
ROTOR_SETTLE_S = 1.0  # the first slew waits this long with the rotors spun up (their transient over)
MAX_SPINUP_S = 20.0  # rotors that never get there are given up on (a fault in the record)
DEAD_SPINUP_S = 3.0  # ... this soon once the board reports a dead ESC
MAX_GAP_S = 1.0  # s: a pause in the phone's stamps longer than this restarts the estimator (not integrated)
DROP_NOTE_S = 0.1  # a reason's dropped readings make at most one journal record per this long (s)


def _time_order(sample: SensorSample) -> tuple[bool, float]:
    """Sort key: by time stamp, the stamps that are not numbers last (the guard drops them)."""
    t = sample.t_s
    return (True, 0.0) if not math.isfinite(t) else (False, t)


class Phase(enum.IntEnum):
    WARMUP = 0
    SLEW = 1
    HOLD = 2
    SUSPENDED = 3  # disarmed by the operator: no reference, no requirement clock, until the operator's Arm


@dataclass(frozen=True)
class TruthSample:
    """What a simulation knows and a real board does not: attitude ``R`` (3, 3), body rate (3,) rad/s."""

    R: Array
    omega: Array


@dataclass
class HostCounters:
    estimator_steps: int = 0
    samples: int = 0
    control_ticks: int = 0
    setpoint_errors: int = 0
    phone_restarts: int = 0


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
        from hil.estimation.multirate import Merger
        from hil.vscmg import PlantModel as Plant

        sc = self.scenario
        loop = sc.loop
        self.params = sc.spacecraft
        plant = Plant(self.params)
        state0 = plant.state(gimbal_angle=sc.slew.gimbal_angle0)
        self._make_estimator = self.make_estimator or sc.make_estimator
        self.filter: Estimator = self._make_estimator()
        self.merger = Merger()
        self.controller = AttitudeController(plant.locked_inertia(state0)[0], loop.gains)
        self.steering = VscmgSteering(self.params, loop.steering)
        self.setpoints = SetpointGenerator(self.params, loop.control_rate_hz, loop.frame_rate_hz)
        self.dt = 1.0 / loop.control_rate_hz
        self.phase = Phase.WARMUP
        self.estimate: Any = None
        self.still_since: float | None = None
        self.spinup_since: float | None = None
        self.spun_since: float | None = None  # the rotors within SPUN_UP of nominal since (this warm-up)
        self.bias_samples: list[Array] = []  # raw gyro samples over the still window's second half
        self._collecting_bias = False
        self.gyro_bias = np.zeros(3)  # measured over the still window: the estimator's bias from then on
        self.target: Array | None = None if self.hold else sc.slew.R_target
        self.slew: EigenaxisSlew | None = None
        self.slew_start: float | None = None
        self.finished = False
        self.lost: str | None = None  # why the run lost the board (or the phone), if it did
        self.n = self.params.n_units
        self.journal = FaultJournal(self.recover_within_s)
        self.watch = BoardWatch(self.client, self.events, self.journal, self.stale_after_s)
        self.in_control = True
        self.need_still = True  # the warm-up's still window is due (the first one, or the phone's back)
        self._rest_still = False  # the first still window runs before the spin-up (the rotors at rest)
        self._resume_still = False  # the phone went away while suspended: the Arm's warm-up has its window
        self._hold = ActuatorSetpoint(
            gimbal_mode=GimbalMode.RATE,
            units=tuple(UnitSetpoint(0.0, self.params.nominal_rotor_speed) for _ in range(self.n)),
        )
        self._rest = ActuatorSetpoint(  # the first still window's: nothing on board turns
            gimbal_mode=GimbalMode.RATE, units=tuple(UnitSetpoint(0.0, 0.0) for _ in range(self.n))
        )
        self._hold_sent = False  # the hold setpoint went out since the board was last seen
        self._hold_tick = -1  # the control tick it went out in
        self.guard = PhoneGuard()  # the admission policy and the phone's clock guard
        self.actuators = ActuatorWatch(self.n, self.journal, self.events, self.setpoints.max_lead)
        self._given_up: set[int] = set()  # units whose rotor never reached speed: not waited for again
        self._drops: dict[str, tuple[float, int]] = {}  # reason -> (last noted at, dropped since)
        self.phone_count = 0  # accepted samples seen at the last tick
        self.phone_heard: float | None = None  # host time the count last moved
        self.trace = RunTrace()
        self.columns = telemetry_columns(self.n)
        self.target9: so3.Mat9 | None = None if self.target is None else so3.mat9(self.target)
        self.operator_log: list[dict[str, Any]] = []  # each operator command, its last status (summary)
        self.suspended_since: float | None = None  # the operator's Disarm suspended the run at (host s)
        self.suspended_s = 0.0  # closed suspensions in all (host s): the run's time limit moves by this
        self.suspended_after_slew_s = 0.0  # ... of it after the slew's start: the requirement clock's
        self._resume_phase = Phase.WARMUP  # where an operator's Arm takes the run back to
        self.rows = TickRecorder(self)

    # ------------------------------------------------------------------ estimator task
    def feed(self, samples: Sequence[SensorSample], now: float | None = None) -> None:
        """Phone samples (any order within a batch) through the admission policy and clock guard
        (:mod:`hil.estimation.admission`: absurd, spoofed and flooding readings dropped and counted; a
        stream whose clock really moved re-anchored) and hold-last-sample merging into the estimator;
        ``now``: the host's time (s), for the record."""
        collecting = self._collecting_bias
        guard = self.guard
        for sample in sorted(samples, key=_time_order):
            self.counters.samples += 1
            newest = guard.newest
            verdict = guard.admit(sample, now)
            if verdict is Verdict.DROP:
                self._note_drop(guard.last_reason, now)
                continue
            if verdict is not Verdict.ACCEPT:
                self._phone_reanchored(verdict, sample.t_s, now)
            elif sample.t_s - newest > MAX_GAP_S and self.estimate is not None:
                self._restart_estimator()  # a stream that paused: not integrated across
                t = now if now is not None else sample.t_s
                self.events.write(t, "estimator_restart", gap_s=sample.t_s - newest)
            if collecting and sample.kind is SensorKind.GYR:
                self.bias_samples.append(np.asarray(sample.xyz, dtype=float))
            for step in self.merger.push(sample):
                self.estimate = self.filter.step(step)
                self.counters.estimator_steps += 1

    def _note_drop(self, reason: str | None, now: float | None) -> None:
        """A dropped reading into the journal and ``events.jsonl``: the first of each reason, then one
        record per :data:`DROP_NOTE_S` with the count since (a flood makes a few records, not one each).
        Duplicates are the merger's ordinary business (a phone's jitter), not a fault."""
        if reason is None or reason == "duplicate":
            return
        t = now if now is not None else (self.phone_heard or 0.0)
        first, count = self._drops.get(reason, (-math.inf, 0))
        if t - first < DROP_NOTE_S:
            self._drops[reason] = (first, count + 1)
            return
        self._drops[reason] = (t, 0)
        total = self.guard.stats.dropped[reason]
        self.journal.note(t, "readings_dropped", reason=reason, since_last=count + 1, total=total)
        self.events.write(t, "readings_dropped", reason=reason, since_last=count + 1, total=total)
        if count == 0:
            logger.warning("phone reading dropped at t=%.3f s: %s (counted)", t, reason)

    def _restart_estimator(self) -> None:
        """The merger and the estimator afresh, from the next measurements (the gyro bias measured so far
        kept): after a stream's clock moved, or a pause longer than :data:`MAX_GAP_S` — integrating the
        held gyro across it would be a guess, and its cost grows with the gap (sub-steps)."""
        from hil.estimation.multirate import Merger

        self.merger = Merger(self.merger.policy)
        self.filter = self._make_estimator()
        self.filter.set_gyro_bias(self.gyro_bias)
        self.filter.set_rest_learning(self.slew_start is None)
        self.estimate = None

    def _phone_reanchored(self, verdict: Verdict, t_s: float, now: float | None) -> None:
        """The phone stream's clock moved (:class:`~hil.estimation.admission.PhoneGuard`): restarted (an
        app restarted, firmware-sim's world started over) or jumped forward. Integrating across the jump
        would be wrong either way: the merger and the estimator start afresh from the measurements (the
        gyro bias is kept), and the warm-up's still window lets the estimate converge before the host
        steers again."""
        kind = "phone_restart" if verdict is Verdict.RESTART else "phone_jump"
        self.counters.phone_restarts += 1
        detail = {"newest_s": self.guard.anchored_from, "sample_s": t_s}
        self._restart_estimator()
        self.phone_count = 0
        t = now if now is not None else (self.phone_heard or 0.0)
        self.journal.fault(t, kind, **detail)
        self.events.write(t, kind, **detail)
        self._restart_warmup(t, kind, still=True)

    # ------------------------------------------------------------------ control task
    def tick(self, t: float, events: Sequence[Any]) -> None:
        """One control period at host time ``t`` (s), after the board client's new ``events``."""
        self.counters.control_ticks += 1
        watch = self.watch
        watch.on_events(events)
        for why in watch.take_upsets():
            self._restart_warmup(t, why, still=False)
        phone_fresh = self._watch_phone(t)
        view = watch.view(t)
        watch.rearm_if_needed(t)
        self.in_control = watch.in_control(t, view, phone_fresh)
        lost = self.journal.overdue(t)
        if lost is not None and self.lost is None:
            self.lost = lost
            self.finished = True
            self.events.write(t, "lost", why=lost)
            logger.error("%s", lost)
        tel = view.telemetry
        if tel is None or len(tel.units) != self.n:
            self._hold_if_blind()
            hold = self._hold if self._hold_tick == self.counters.control_ticks else None
            self.rows.blind(t, view, hold)
            return
        self._hold_sent = False
        self.actuators.board_flags(t, tel.faults)
        gimbal = np.array([u.gimbal_angle for u in tel.units])
        rotor = np.array([u.rotor_speed for u in tel.units])
        armed = tel.state is BoardState.ARMED
        command, cmd_out, ref = self._control(t, gimbal, rotor, armed, phone_fresh)
        if armed and not watch.rearm_pending and command is not None:
            self._send(command)
            if cmd_out is not None:  # the steering's: what the actuators should follow
                self.actuators.following(t, rotor, tel.units, command)
        self.rows.live(t, tel, view, gimbal, rotor, command, cmd_out, ref)
        if self.suspended_since is None and self.slew_start is not None:
            if t - self.slew_start - self.suspended_after_slew_s >= self._duration - 1e-9:
                self.finished = True

    def _send(self, command: ActuatorSetpoint) -> None:
        try:
            self.client.send_setpoint(command)
        except BoardReset:  # the reset event arrives with the next service(); re-armed then
            self.counters.setpoint_errors += 1

    def _hold_if_blind(self) -> None:
        """The host cannot see the board: it stops commanding it. One hold setpoint (gimbals still, rotors
        at nominal speed) goes out when it loses sight of it, if the link carries it, so that a board that
        still hears the host does not carry on with a command made from what is now stale."""
        if self._hold_sent or not self.client.connected or self.watch.rearm_pending:
            return
        self._hold_sent = True
        self._hold_tick = self.counters.control_ticks
        self._send(self._hold)

    def _watch_phone(self, t: float) -> bool:
        """Whether the phone's samples are fresh at ``t`` (the merger accepted one within
        ``stale_after_s``, or none has come yet); a gap is a fault, and the warm-up (with its still window)
        follows it."""
        count = sum(self.merger.stats.accepted.values())
        if count != self.phone_count:
            self.phone_count = count
            self.phone_heard = t
            back = self.journal.phone_back(t)
            if back is not None:
                self.events.write(t, "phone_back", since=back.start, gap_s=t - back.start)
            return True
        heard = self.phone_heard
        if heard is None or t - heard <= self.stale_after_s:
            return True
        if self.journal.phone_out is None:
            self.journal.fault(t, "phone_gap", since=heard)
            self.events.write(t, "phone_gap", since=heard)
            logger.warning("no phone sample for %.2f s at t=%.3f s: holding", t - heard, t)
            self._restart_warmup(t, "phone_gap", still=True)
        return False

    @property
    def _duration(self) -> float:
        return self.scenario.slew.duration_s if self.duration_s is None else self.duration_s

    def _control(
        self, t: float, gimbal: Array, rotor: Array, armed: bool, phone_fresh: bool
    ) -> tuple[ActuatorSetpoint | None, Any, Reference | None]:
        if self.phase is Phase.SUSPENDED:
            return None, None, None  # the operator disarmed the board: nothing to command
        if self.phase is Phase.WARMUP:
            self._warm_up(t, rotor, armed, phone_fresh)
            if self.phase is Phase.WARMUP:
                return (self._rest if self._resting else self._hold), None, None
        assert self.slew is not None and self.estimate is not None
        if self.phase is Phase.SLEW and t >= self.slew.start_s + self.slew.duration_s:
            self.phase = Phase.HOLD
            self.events.write(t, "slew_end")
        ref = self.slew.at(t)
        R_hat, w_hat = np.asarray(self.estimate.R), np.asarray(self.estimate.omega)
        h = self.steering.momentum(gimbal, rotor)[0]
        out = self.controller.update(R_hat, w_hat, ref, self.dt, h)
        cmd = self.steering.solve(out.torque, gimbal, rotor, self.dt)
        sp = self.setpoints.update(cmd, rotor)
        return sp.message(), (out, cmd), ref

    @property
    def _resting(self) -> bool:  # the first warm-up's still window, before the spin-up: rotors held stopped
        return self._rest_still and self.spinup_since is None

    def _warm_up(self, t: float, rotor: Array, armed: bool, phone_fresh: bool) -> None:
        """The still window when due, spin-up (gimbals still), checks; then the slew (the scenario's, or
        after a recovery a new one to the target). The first still window comes *before* the spin-up when
        the rotors are at rest: spun-up rotors on gimbal axes a few mrad off nominal turn the body, which a
        later window took for gyro bias (docs/montecarlo.md). A later one keeps the rotors spinning."""
        if not armed or self.watch.rearm_pending:
            return
        nominal = self.params.nominal_rotor_speed
        first = self.slew_start is None
        if first and self.need_still and self.spinup_since is None and self.still_since is None:
            self._rest_still = bool(np.all(np.abs(rotor) <= SPUN_UP * nominal))
        if self._resting:
            if not self._still_window(t, rotor, phone_fresh):
                return
            self._rest_still = False
        if self.spinup_since is None:
            self.spinup_since = t
            self.events.write(t, "spin_up", nominal_rad_s=nominal)
        if self.still_since is None or not self.need_still:  # not during a still window once begun
            if not self._spun_up(t, rotor, nominal):
                return
            if self.spun_since is None:
                self.spun_since = t
        if self.need_still and not self._still_window(t, rotor, phone_fresh):
            return
        if self.estimate is None or not phone_fresh:
            return
        if not first:
            self._resume(t, rotor)
        elif self.spun_since is not None and t - self.spun_since >= ROTOR_SETTLE_S:
            self._start_slew(t, rotor)

    def _spun_up(self, t: float, rotor: Array, nominal: float) -> bool:
        """Whether every rotor the host still counts on is within :data:`SPUN_UP` of ``nominal``. A rotor
        that does not get there within :data:`MAX_SPINUP_S` of the spin-up (:data:`DEAD_SPINUP_S` once the
        board reports a dead ESC) is given up on — a fault in the record (``spin_up_failed``) — and the
        host goes on with the array it has (steering degrades gracefully; the run's requirement says
        why it was missed), rather than end the run."""
        off = np.abs(rotor - nominal) > SPUN_UP * nominal
        off[list(self._given_up)] = False
        if not off.any():
            return True
        assert self.spinup_since is not None
        waited = t - self.spinup_since
        if waited > MAX_SPINUP_S or (self.actuators.esc_dead and waited > DEAD_SPINUP_S):
            units = [int(i) for i in np.nonzero(off)[0]]
            self._given_up.update(units)
            speeds = rotor.round(1).tolist()
            self.journal.note(t, "spin_up_failed", units=units, rotor_rad_s=speeds)
            self.events.write(t, "spin_up_failed", units=units, rotor_rad_s=speeds)
            logger.error(
                "units %s did not reach %.0f rad/s within %.0f s (telemetry %s rad/s): going on without them",
                units,
                nominal,
                waited,
                speeds,
            )
            return True
        return False

    def _still_window(self, t: float, rotor: Array, phone_fresh: bool) -> bool:
        """The still window (``warmup_s``; the first one's second half gives the gyro bias): True once it
        is over (``need_still`` cleared)."""
        if self.still_since is None:
            if not phone_fresh:
                return False  # the still window is the estimator's: it starts when the phone streams again
            self.still_since = t
            self.events.write(t, "still_window", rotor_rad_s=rotor.round(1).tolist())
        if self.estimate is None or not phone_fresh:
            return False
        warmup_s = self.scenario.loop.warmup_s
        first = self.slew_start is None
        self._collecting_bias = first and t - self.still_since >= 0.5 * warmup_s
        if t - self.still_since < warmup_s:
            return False
        self._collecting_bias = False
        self.need_still = False
        if first and self.scenario.loop.calibrate_rate_bias and self.bias_samples:
            self.gyro_bias = np.mean(self.bias_samples, axis=0)
            self.filter.set_gyro_bias(self.gyro_bias)
        return True

    def _start_slew(self, t: float, rotor: Array) -> None:
        """The end of the first warm-up: the scenario's slew from the attitude estimated now."""
        online = self.filter.gyro_bias  # what the estimator had found by itself
        # from now on the spacecraft moves under control: a slew's slow end or a hold turns steadily below
        # the rest detector's rate bound, and learning that as bias would be wrong (4.8° off after a 90°
        # slew); the variational bias law keeps correcting the estimate in motion
        self.filter.set_rest_learning(False)
        R_hat = np.asarray(self.estimate.R)
        sl = self.scenario.slew
        self.target = R_hat.copy() if self.hold else sl.R_target
        self.target9 = so3.mat9(self.target)
        self.slew = EigenaxisSlew.within_limits(R_hat, self.target, sl.max_rate, sl.max_accel, start_s=t)
        self.slew_start = t
        self.setpoints.reset(rotor)
        self.controller.reset()
        self.phase = Phase.SLEW
        self.events.write(
            t, "slew_start", angle_deg=math.degrees(so3.principal_angle(R_hat.T @ self.target)),
            slew_s=self.slew.duration_s, gyro_bias=self.gyro_bias.tolist(),
            gyro_bias_online=online.tolist(),
        )  # fmt: skip

    def _resume(self, t: float, rotor: Array) -> None:
        """The end of a recovery: a new slew from the attitude estimated now to the target."""
        assert self.estimate is not None and self.target is not None
        R_hat = np.asarray(self.estimate.R)
        sl = self.scenario.slew
        self.slew = EigenaxisSlew.within_limits(R_hat, self.target, sl.max_rate, sl.max_accel, start_s=t)
        self.setpoints.reset(rotor)
        self.controller.reset()
        self.phase = Phase.SLEW
        self.events.write(
            t, "resume", angle_deg=math.degrees(so3.principal_angle(R_hat.T @ self.target)),
            slew_s=self.slew.duration_s,
        )  # fmt: skip

    def retarget(self, t: float, R_target: Array | None = None) -> str | None:
        """A new target from outside the loop (the ground station's slew or hold): an eigenaxis slew from the
        attitude estimated now to ``R_target`` (3, 3), body → inertial (None: hold the attitude estimated
        now), within the scenario's rate and acceleration limits, from ``t`` (s). The run still ends
        ``duration_s`` after the scenario's slew started. Returns why it was refused, or None: during the
        first warm-up there is no estimate to start from and the scenario's own slew is still to come.
        During a recovery's warm-up (or while the operator has the run suspended) the target is taken and
        the slew to it starts when the recovery ends (planned anew from the attitude estimated then)."""
        if self.slew_start is None or self.estimate is None:
            return "the warm-up is not over (the scenario's slew has not started)"
        R_hat = np.asarray(self.estimate.R)
        self.target = R_hat.copy() if R_target is None else np.asarray(R_target, dtype=float)
        self.target9 = so3.mat9(self.target)
        sl = self.scenario.slew
        self.slew = EigenaxisSlew.within_limits(R_hat, self.target, sl.max_rate, sl.max_accel, start_s=t)
        if self.phase in (Phase.SLEW, Phase.HOLD):
            self.phase = Phase.SLEW
        return None

    def arm(self, t: float, origin: str = "gcs") -> Command:
        """The operator's Arm (sent now): the host re-arms on its own again after later faults. After the
        operator's Disarm it ends the suspension: the warm-up runs again (spin-up, checks; the still
        window too if the phone went away meanwhile), then a new slew from the attitude estimated then to
        the target (the first warm-up starts over if the scenario's slew had not started)."""
        cmd = self.watch.operator_arm(t)
        since = self.suspended_since
        if since is not None:
            self.suspended_since = None
            self.suspended_s += t - since
            if self.slew_start is not None:
                self.suspended_after_slew_s += t - max(since, self.slew_start)
            self.phase = Phase.WARMUP
            self._restart_warmup(t, "operator_arm", still=self._resume_still, force=True)
            self.events.write(t, "suspension_end", by=origin, suspended_s=t - since)
        return cmd

    def disarm(self, t: float, origin: str = "gcs") -> Command:
        """The operator's Disarm (sent now): a re-arm the host had pending is cancelled and the run is
        *suspended* — no reference (the slew does not go on without the actuators), no setpoints, no
        requirement clock, no re-arming on the host's own account — until :meth:`arm`. A run that ends
        suspended did not complete (``hil.runtime.loop``)."""
        if self.suspended_since is None:
            self.suspended_since = t
            self._resume_still = False
            self.phase = Phase.SUSPENDED
            self.events.write(t, "suspended", by=origin)
        # Without a session the Disarm cannot go out (LinkError, the operator's record says so), yet the
        # run stays suspended and the host never re-arms: the board, failed safe for want of the link,
        # comes back disarmed from its next handshake.
        return self.watch.operator_disarm(t)

    def record_command(self, t: float, command: Any, status: str, **fields: Any) -> None:
        """An operator command's step (:mod:`hil.runtime.operator`): an ``events.jsonl`` record, and its
        entry in :attr:`operator_log` (created at its first step, updated with its last status)."""
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
        for entry in reversed(self.operator_log):
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
        self.operator_log.append(entry)

    @property
    def time_limit_extension_s(self) -> float:
        """How far the operator's suspensions (closed ones) move the run's time limit (s)."""
        return self.suspended_s

    def _restart_warmup(self, t: float, why: str, still: bool, force: bool = False) -> None:
        """The board left the state the host commanded (failsafe, reset, link loss, reconnect) or the
        phone went away: back to the warm-up — spin-up and checks; the still window too if ``still`` (the
        phone), or if the first warm-up was not over (its bias window then starts again). While the
        operator has the run suspended it stays so; the warm-up the operator's Arm starts then includes
        the still window if the phone went away meanwhile."""
        if self.phase is Phase.SUSPENDED:
            self._resume_still = self._resume_still or still
            self.events.write(t, "fault_while_suspended", reason=why)
            return
        started = self.spinup_since is not None or self.still_since is not None
        if not force and self.phase is Phase.WARMUP and not started and not (still and not self.need_still):
            return  # nothing under way to restart
        first = self.slew_start is None
        self.phase = Phase.WARMUP
        self.spinup_since = self.still_since = self.spun_since = None
        self.need_still = self.need_still or still or first
        if first:
            self.bias_samples.clear()
        self._collecting_bias = False
        self.events.write(t, "warmup_restart" if first else "recovery_start", reason=why)

    # ------------------------------------------------------------------ summary
    def summary(self) -> dict[str, Any]:
        """The run's figures: settle time (first time after which the pointing error stays ≤ settle_deg,
        from the slew's start), final and peak pointing error, peak gimbal rate, minimum δ, the
        estimator's RMSE over slew + hold (simulated runs); the faults — failsafes, resets, link losses,
        reconnects, stale telemetry, phone gaps, each with its time and cause — and the outages they made
        (:meth:`hil.runtime.faults.FaultJournal.summary`); None where not reached."""
        sc = self.scenario
        w = self.watch
        now = self.client.clock.now()
        since = self.suspended_since
        out: dict[str, Any] = {
            "scenario": sc.name,
            "settle_requirement_deg": sc.settle_deg,
            "slew_started": self.slew_start is not None,
            "failsafe_events": w.failsafes,
            "board_resets": w.resets,
            "link_lost": w.link_losses,
            "reconnects": w.reconnects,
            "rearms": w.rearms,
            "stale_episodes": w.stale_episodes,
            "phone_gaps": len(self.journal.phone_gaps),
            "phone_restarts": self.counters.phone_restarts,
            "lost": self.lost or self.journal.open_at_end(now),
            "estimator_steps": self.counters.estimator_steps,
            "phone_samples": self.counters.samples,
            "control_ticks": self.counters.control_ticks,
            "max_gimbal_rate_limit": self.params.limits.max_gimbal_rate,
            "operator": [dict(entry) for entry in self.operator_log],
            "operator_commands": len(self.operator_log),
            "suspended_s": self.suspended_s + (0.0 if since is None else now - since),
            "suspended_at_end": self.suspended_since,
        }
        out.update(self.trace.figures(sc.settle_deg, self.params.limits.max_gimbal_rate))
        if len(self.trace):
            out["slew_s"] = None if self.slew is None else self.slew.duration_s
        out["estimator_rmse_deg"] = self.rows.estimator_rmse()
        out["phone_admission"] = self.guard.as_dict()
        out["requirement"] = self._requirement(out, now)
        journal = self.journal.summary(now)
        out["phone_gap_list"] = journal.pop("phone_gaps")
        out.update(journal)
        return out

    def _damaged_frames(self) -> int:
        """Frames damaged on the link, either way (the host's deframer and the board's receiver)."""
        try:
            stats = self.client.stats()
        except HilError:
            return 0
        return sum(stats.bad_frames.values()) + (stats.board_rx_bad or 0)

    def _requirement(self, figures: dict[str, Any], now: float) -> dict[str, Any]:
        """Whether the run met its pointing requirement (settled within ``settle_deg``) and, when it did
        not, why — what the record holds that explains it: the operator's suspensions and retargets, the
        faults since the slew started, a recovery that left too little time. ``explained`` is False when
        nothing in the record explains a miss (a controller that did not settle on its own)."""
        if figures.get("settled"):
            return {"met": True, "why": None, "explained": True}
        reasons: list[str] = []
        if self.slew_start is None:
            reasons.append("the slew never started")
        suspended = figures.get("suspended_s") or 0.0
        if suspended > 0 or self.suspended_since is not None:
            reasons.append(f"disarmed by the operator for {suspended:.1f} s")
        retargets = [
            o for o in self.operator_log if o["command"] in ("slew", "hold") and o["status"] == "applied"
        ]
        if retargets:
            reasons.append(f"retargeted by the operator at t={retargets[-1]['t']:.1f} s")
        since = -math.inf if self.slew_start is None else self.slew_start
        kinds: dict[str, int] = {}
        for f in self.journal.faults:
            if f["t"] >= since:
                kinds[f["kind"]] = kinds.get(f["kind"], 0) + 1
        if kinds:
            reasons.append("faults: " + ", ".join(f"{k} x{n}" for k, n in kinds.items()))
        damaged = self._damaged_frames()
        if damaged:
            reasons.append(f"link: {damaged} damaged frames (setpoints and telemetry lost with them)")
        if self.slew is not None and self.slew_start is not None:
            left = now - self.slew.start_s
            if left < self.slew.duration_s:
                reasons.append(
                    f"steering from t={self.slew.start_s:.1f} s, {left:.1f} s before the end: its slew "
                    f"needed {self.slew.duration_s:.1f} s"
                )
        explained = bool(reasons)
        if not reasons:
            reasons.append("nothing in the record explains it: the controller did not settle")
        return {"met": False, "why": "; ".join(reasons), "explained": explained}
