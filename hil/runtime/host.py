"""The host's closed loop for one run: phone samples → merge → estimator, and at the control rate
estimate → controller → steering → setpoints for the board, with the run's phases, its telemetry rows and
its summary. No clock or thread of its own: :mod:`hil.runtime.loop` calls :meth:`Host.feed` from the
estimator task and :meth:`Host.tick` from the control task, in real time or in lockstep.

Phases (``telemetry.csv`` column ``phase``):

0. **warm-up** — the board is armed, the rotors spin up to their nominal speed with the gimbals still;
   once every rotor is within 5 % of it the still window of ``warmup_s`` starts: the estimator converges
   and the raw gyroscope samples of the window's second half are averaged into the gyro bias, which
   becomes the estimator's bias estimate — the tuned estimator keeps refining it online, at rest and in
   motion (the phone gyro's residual bias would otherwise leave a steady attitude error and a rate offset
   in the control loop);
1. **slew** — an eigenaxis rest-to-rest slew from the estimated attitude to the scenario's target within
   its rate and acceleration limits, tracked by the geometric controller;
2. **hold** — the reference stays at the target.

With ``hold=True`` (``hil replay --port``: a recorded phone's motion, which the actuators cannot change)
the target is the attitude estimated at the end of the warm-up: the controller then commands what it
takes to hold that attitude against the recorded motion.

The run ends ``duration_s`` after the slew started. A board in FAILSAFE (link watchdog) or reset is
re-armed as soon as the link answers again; each such episode is counted and logged.
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
from hil.estimation.sensors import SensorKind, SensorSample
from hil.link.board import BoardClient
from hil.link.board.events import (
    BoardResetEvent,
    ConnectedEvent,
    LinkLostEvent,
    LogEvent,
    SilenceEvent,
    StateEvent,
)
from hil.runtime.runlog import CsvLog, EventLog
from hil.runtime.telemetry import RunTrace, angle_between9, log9, mat9, telemetry_columns
from hil.scenario import Scenario
from protocol.errors import BoardReset, CommandFailed, LinkError
from protocol.messages import ActuatorSetpoint, Arm, BoardState, GimbalMode, UnitSetpoint

logger = logging.getLogger(__name__)

Array = NDArray[np.float64]

SPUN_UP = 0.05  # rotors within this fraction of nominal: the still window may start
MAX_SPINUP_S = 20.0  # rotors that never get there: the run fails with a clear error


class Phase(enum.IntEnum):
    WARMUP = 0
    SLEW = 1
    HOLD = 2


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
    failsafe_events: int = 0
    resets: int = 0
    link_lost: int = 0
    rearms: int = 0
    setpoint_errors: int = 0


@dataclass
class Host:
    """One run's host side. ``truth`` (optional) returns the simulation's truth now (None on hardware);
    ``telemetry`` None keeps no telemetry rows (a Monte Carlo run: its figures come from :attr:`trace`)."""

    scenario: Scenario
    client: BoardClient
    telemetry: CsvLog | None
    events: EventLog
    truth: Callable[[], TruthSample | None] = lambda: None
    duration_s: float | None = None
    filter_config: Any = None  # the estimator's FilterConfig (default: the scenario's phone)
    hold: bool = False  # target the attitude estimated at the end of the warm-up, not the scenario's
    counters: HostCounters = field(default_factory=HostCounters)

    def __post_init__(self) -> None:
        from hil.estimation.filter import AttitudeFilter
        from hil.estimation.multirate import Merger
        from hil.vscmg import Plant

        sc = self.scenario
        loop = sc.loop
        self.params = sc.spacecraft
        plant = Plant(self.params)
        state0 = plant.state(gimbal_angle=sc.slew.gimbal_angle0)
        self.filter = AttitudeFilter(self.filter_config or sc.filter_config())
        self.merger = Merger()
        self.controller = AttitudeController(plant.locked_inertia(state0)[0], loop.gains)
        self.steering = VscmgSteering(self.params, loop.steering)
        self.setpoints = SetpointGenerator(self.params, loop.control_rate_hz, loop.frame_rate_hz)
        self.dt = 1.0 / loop.control_rate_hz
        self.phase = Phase.WARMUP
        self.estimate: Any = None
        self.still_since: float | None = None
        self.spinup_since: float | None = None
        self.bias_samples: list[Array] = []  # raw gyro samples over the still window's second half
        self._collecting_bias = False
        self.gyro_bias = np.zeros(3)  # measured over the still window: the estimator's bias from then on
        self.target: Array | None = None if self.hold else sc.slew.R_target
        self.slew: EigenaxisSlew | None = None
        self.slew_start: float | None = None
        self.finished = False
        self.n = self.params.n_units
        self._rearm: Any = None
        self._errors_sq: list[float] = []
        self.trace = RunTrace()
        self.columns = telemetry_columns(self.n)
        self._target9: tuple[float, ...] | None = None if self.target is None else mat9(self.target)
        self._none3 = (None, None, None)

    # ------------------------------------------------------------------ estimator task
    def feed(self, samples: Sequence[SensorSample]) -> None:
        """Phone samples (any order within a batch) through hold-last-sample merging into the estimator."""
        collecting = self._collecting_bias
        for sample in sorted(samples, key=lambda s: s.t_s):
            self.counters.samples += 1
            if collecting and sample.kind is SensorKind.GYR:
                self.bias_samples.append(np.asarray(sample.xyz, dtype=float))
            for step in self.merger.push(sample):
                self.estimate = self.filter.step(step)
                self.counters.estimator_steps += 1

    # ------------------------------------------------------------------ control task
    def tick(self, t: float, events: Sequence[Any]) -> None:
        """One control period at host time ``t`` (s), after the board client's new ``events``."""
        self.counters.control_ticks += 1
        for event in events:
            self._on_event(event)
        self._rearm_if_needed(t)
        tel = self.client.telemetry
        if tel is None or len(tel.units) != self.n:
            return
        gimbal = np.array([u.gimbal_angle for u in tel.units])
        rotor = np.array([u.rotor_speed for u in tel.units])
        armed = tel.state is BoardState.ARMED
        command, cmd_out, ref = self._control(t, gimbal, rotor, armed)
        if armed and self._rearm is None:
            try:
                self.client.send_setpoint(command)
            except BoardReset:  # the reset event arrives with the next service(); re-armed then
                self.counters.setpoint_errors += 1
        self._record(t, tel, gimbal, rotor, command, cmd_out, ref)
        if self.slew_start is not None and t - self.slew_start >= self._duration - 1e-9:
            self.finished = True

    @property
    def _duration(self) -> float:
        return self.scenario.slew.duration_s if self.duration_s is None else self.duration_s

    def _control(
        self, t: float, gimbal: Array, rotor: Array, armed: bool
    ) -> tuple[ActuatorSetpoint, Any, Reference | None]:
        nominal = self.params.nominal_rotor_speed
        loop = self.scenario.loop
        if self.phase is Phase.WARMUP:
            self._warm_up(t, rotor, nominal, armed, loop.warmup_s)
            hold = ActuatorSetpoint(
                gimbal_mode=GimbalMode.RATE, units=tuple(UnitSetpoint(0.0, nominal) for _ in range(self.n))
            )
            return hold, None, None
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

    def _warm_up(self, t: float, rotor: Array, nominal: float, armed: bool, warmup_s: float) -> None:
        if not armed:
            return
        if self.spinup_since is None:
            self.spinup_since = t
            self.events.write(t, "spin_up", nominal_rad_s=nominal)
        if self.still_since is None:
            if np.all(np.abs(rotor - nominal) <= SPUN_UP * nominal):
                self.still_since = t
                self.events.write(t, "still_window", rotor_rad_s=rotor.round(1).tolist())
            elif t - self.spinup_since > MAX_SPINUP_S:
                raise LinkError(
                    f"the rotors did not reach {nominal:.0f} rad/s within {MAX_SPINUP_S:.0f} s "
                    f"(telemetry: {rotor.round(1).tolist()} rad/s)"
                )
            return
        if self.estimate is None:
            return
        self._collecting_bias = t - self.still_since >= 0.5 * warmup_s
        if t - self.still_since >= warmup_s:
            self._collecting_bias = False
            online = self.filter.gyro_bias  # what the estimator had found by itself
            if self.scenario.loop.calibrate_rate_bias and self.bias_samples:
                self.gyro_bias = np.mean(self.bias_samples, axis=0)
                self.filter.set_gyro_bias(self.gyro_bias)
            R_hat = np.asarray(self.estimate.R)
            sl = self.scenario.slew
            self.target = R_hat.copy() if self.hold else sl.R_target
            self._target9 = mat9(self.target)
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

    def retarget(self, t: float, R_target: Array | None = None) -> str | None:
        """A new target from outside the loop (the ground station's slew or hold): an eigenaxis slew from the
        attitude estimated now to ``R_target`` (3, 3), body → inertial (None: hold the attitude estimated
        now), within the scenario's rate and acceleration limits, from ``t`` (s). The run still ends
        ``duration_s`` after the scenario's slew started. Returns why it was refused, or None: during the
        warm-up there is no estimate to start from and the scenario's own slew is still to come."""
        if self.phase is Phase.WARMUP or self.estimate is None:
            return "the warm-up is not over (the scenario's slew has not started)"
        R_hat = np.asarray(self.estimate.R)
        self.target = R_hat.copy() if R_target is None else np.asarray(R_target, dtype=float)
        sl = self.scenario.slew
        self.slew = EigenaxisSlew.within_limits(R_hat, self.target, sl.max_rate, sl.max_accel, start_s=t)
        self.phase = Phase.SLEW
        return None

    # ------------------------------------------------------------------ board events
    def _on_event(self, event: Any) -> None:
        t = event.t
        if isinstance(event, StateEvent):
            old = None if event.old is None else event.old.name
            self.events.write(t, "board_state", old=old, new=event.new.name)
            if event.new is BoardState.FAILSAFE:
                self.counters.failsafe_events += 1
                logger.warning("board in FAILSAFE at t=%.3f s (link watchdog): re-arming", t)
                self._want_rearm()
                self._restart_warmup(t)
        elif isinstance(event, BoardResetEvent):
            self.counters.resets += 1
            self.events.write(t, "board_reset", cause=event.cause.name, evidence=event.evidence)
            self._want_rearm()
            self._restart_warmup(t)
        elif isinstance(event, LinkLostEvent):
            self.counters.link_lost += 1
            self.events.write(t, "link_lost", reason=event.reason)
        elif isinstance(event, ConnectedEvent):
            self.events.write(t, "connected", reconnects=event.reconnects)
            if event.reconnects:
                self._want_rearm()
        elif isinstance(event, SilenceEvent):
            self.events.write(t, "silence", since=event.since, ended=event.ended)
        elif isinstance(event, LogEvent):
            self.events.write(t, "board_log", severity=event.log.severity.name, text=event.log.text)

    def _restart_warmup(self, t: float) -> None:
        """A failsafe or reset during the warm-up: the rotors coast down, so the still window (and the gyro
        bias measured over it) starts again once they are back at speed after the re-arm."""
        if self.phase is not Phase.WARMUP or (self.spinup_since is None and self.still_since is None):
            return
        self.spinup_since = self.still_since = None
        self.bias_samples.clear()
        self._collecting_bias = False
        self.events.write(t, "warmup_restart")

    def _want_rearm(self) -> None:
        if self._rearm is None:
            self._rearm = "pending"

    def _rearm_if_needed(self, t: float) -> None:
        """Re-arm without blocking the loop: send Arm, then look at the answer on later ticks."""
        if self._rearm is None or not self.client.connected:
            return
        if self._rearm == "pending":
            self._rearm = self.client.command(Arm())
            return
        if not self._rearm.done:
            return
        try:
            self._rearm.result()
            self.counters.rearms += 1
            self.events.write(t, "rearmed")
            self._rearm = None
        except CommandFailed as exc:  # e.g. still in reset: try again next tick
            self.events.write(t, "rearm_failed", detail=str(exc))
            self._rearm = "pending"

    # ------------------------------------------------------------------ telemetry rows
    def _record(
        self, t: float, tel: Any, gimbal: Array, rotor: Array, command: ActuatorSetpoint, cmd_out: Any,
        ref: Reference | None,
    ) -> None:  # fmt: skip
        """The tick's errors into the trace (from the slew's start) and its row into the telemetry log:
        plain floats in column order (:mod:`hil.runtime.telemetry`), formatted by the log's writer thread."""
        truth = self.truth()
        est = self.estimate
        none3 = self._none3
        R_true = w_true = R_hat = w_hat = None
        if truth is not None:
            R_true, w_true = mat9(truth.R), tuple(np.asarray(truth.omega, dtype=float).tolist())
        if est is not None:
            R_hat, w_hat = mat9(est.R), tuple(np.asarray(est.omega, dtype=float).tolist())
        est_err = rate_err = None
        if R_true is not None and R_hat is not None:
            assert w_true is not None and w_hat is not None
            est_err = math.degrees(angle_between9(R_true, R_hat))
            rate_err = math.dist(w_hat, w_true)
            if self.phase is not Phase.WARMUP:
                self._errors_sq.append(est_err * est_err)
        R_att = R_true if R_true is not None else R_hat
        point = track = None
        if R_att is not None and self._target9 is not None:
            point = math.degrees(angle_between9(R_att, self._target9))
            if ref is not None:
                track = math.degrees(angle_between9(R_att, mat9(ref.R)))
        if cmd_out is not None:  # steering computed δ from this telemetry already
            delta = float(cmd_out[1].delta[0])
        else:
            delta = float(self.steering.delta(gimbal, rotor)[0])
        rates = [u.gimbal_rate for u in tel.units]
        if self.slew_start is not None:
            nan = math.nan
            self.trace.append(
                t - self.slew_start, nan if point is None else point, nan if track is None else track,
                nan if est_err is None else est_err, max(abs(r) for r in rates), delta,
            )  # fmt: skip
        if self.telemetry is None:
            return
        n = self.n
        row: list[Any] = [t, int(self.phase), est_err, rate_err, point, track]
        row += none3 if R_hat is None else log9(R_hat)
        row += none3 if R_true is None else log9(R_true)
        row += none3 if w_hat is None else w_hat
        row += none3 if w_true is None else w_true
        row += none3 if cmd_out is None else cmd_out[0].torque.tolist()
        row.append(delta)
        row += gimbal.tolist()
        row += rates
        row += rotor.tolist()
        row += [u.gimbal for u in command.units]
        row += [u.rotor_speed for u in command.units]
        pulses = list(tel.pulses_us[: 2 * n])
        row += pulses + [None] * (2 * n - len(pulses))
        row += [tel.battery_mv / 1000.0, int(tel.state), tel.rx_frames, tel.rx_bad, tel.link_age_ms]
        self.telemetry.write_values(row)

    # ------------------------------------------------------------------ summary
    def summary(self) -> dict[str, Any]:
        """The run's figures: settle time (first time after which the pointing error stays ≤ settle_deg,
        from the slew's start), final and peak pointing error, peak gimbal rate, minimum δ, the
        estimator's RMSE over slew + hold (simulated runs), failsafe events; None where not reached."""
        tr = self.trace.arrays()
        sc = self.scenario
        out: dict[str, Any] = {
            "scenario": sc.name,
            "settle_requirement_deg": sc.settle_deg,
            "slew_started": self.slew_start is not None,
            "failsafe_events": self.counters.failsafe_events,
            "board_resets": self.counters.resets,
            "link_lost": self.counters.link_lost,
            "rearms": self.counters.rearms,
            "estimator_steps": self.counters.estimator_steps,
            "phone_samples": self.counters.samples,
            "control_ticks": self.counters.control_ticks,
            "max_gimbal_rate_limit": self.params.limits.max_gimbal_rate,
        }
        if len(tr["t"]):
            err = tr["point_err_deg"]
            above = np.nonzero(~(err <= sc.settle_deg))[0]
            settled = len(above) == 0 or above[-1] + 1 < len(err)
            out.update(
                settle_s=(float(tr["t"][above[-1] + 1]) if len(above) else 0.0) if settled else None,
                final_error_deg=float(err[-1]),
                peak_error_deg=float(np.nanmax(err)),
                peak_gimbal_rate=float(np.max(tr["gimbal_rate"])),
                min_delta=float(np.min(tr["delta"])),
                slew_s=None if self.slew is None else self.slew.duration_s,
            )
            out["settled"] = bool(settled and out["settle_s"] is not None)
            limit = self.params.limits.max_gimbal_rate
            out["gimbal_rate_within_limit"] = bool(out["peak_gimbal_rate"] <= limit)
        out["estimator_rmse_deg"] = float(np.sqrt(np.mean(self._errors_sq))) if self._errors_sq else None
        return out
