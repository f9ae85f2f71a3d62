"""The run's phases as a state machine: where the run is (``telemetry.csv`` column ``phase``), what moves
it on, and what it holds while it waits — the still window, the spin-up, the gyro bias measured, the
target and the slew to it, the operator's suspensions. The host (:mod:`hil.runtime.host`) drives it on
the control tick and acts on what it says; it sends nothing and steers nothing itself.

Phases:

0. **warm-up** — the board is armed; with the rotors still at rest the still window of ``warmup_s`` runs:
   the estimator converges and the raw gyroscope samples of the window's second half are averaged into
   the gyro bias, the estimator's bias estimate (the tuned estimator, learning it from rest detection in
   the window, refines it online in motion); then the rotors spin up with the gimbals still, and the slew
   starts :data:`ROTOR_SETTLE_S` after every rotor is within :data:`SPUN_UP` of its nominal speed (the
   phone gyro's residual bias would otherwise leave a steady attitude error and a rate offset in the
   control loop);
1. **slew** — an eigenaxis rest-to-rest slew from the estimated attitude to the scenario's target within
   its rate and acceleration limits, tracked by the geometric controller;
2. **hold** — the reference stays at the target;
3. **suspended** — disarmed by the operator: no reference, no requirement clock, until the operator's Arm.

With ``hold=True`` (``hil replay --port``: a recorded phone's motion, which the actuators cannot change)
the target is the attitude estimated at the end of the warm-up: the controller then commands what it
takes to hold that attitude against the recorded motion.

Transitions (each a method of :class:`RunPhases`; the run ends ``duration_s`` after the slew started,
:meth:`RunPhases.time_is_up`):

=====================  ======================  ===============================================================
from                   to                      on
=====================  ======================  ===============================================================
warm-up                slew                    :meth:`~RunPhases.warm_up` over: the first one starts the
                                               scenario's slew, a recovery's a new slew to the target
slew                   hold                    :meth:`~RunPhases.finish_slew`: the slew's time is over
slew, hold             slew                    :meth:`~RunPhases.retarget`: a new target from the operator
any but suspended      warm-up                 :meth:`~RunPhases.restart_warmup`: the board left the state
                                               the host commanded, or the phone went away
any                    suspended               :meth:`~RunPhases.suspend`: the operator's Disarm
suspended              warm-up                 :meth:`~RunPhases.end_suspension`: the operator's Arm
=====================  ======================  ===============================================================

A recovery's warm-up (after a failsafe, a reset, a link loss, a reconnect) has the rotors back at speed
and every check passed before the host steers again. (The rotors of a reset board are stopped: steering
them gives no gimbal authority.) A phone gap or a phone that restarted its clock (the estimator starts
afresh) brings the still window back into the warm-up (the gyro bias measured in the first one is kept).
"""

from __future__ import annotations

import enum
import logging
import math

import numpy as np
from numpy.typing import NDArray

from hil import so3
from hil.control.attitude import EigenaxisSlew
from hil.estimation.interface import Estimator
from hil.runtime.faults import FaultJournal
from hil.runtime.runlog import EventLog
from hil.scenario import Scenario

logger = logging.getLogger(__name__)

Array = NDArray[np.float64]

SPUN_UP = 0.05  # rotors within this fraction of nominal: the still window may start
ROTOR_SETTLE_S = 1.0  # the first slew waits this long with the rotors spun up (their transient over)
MAX_SPINUP_S = 20.0  # rotors that never get there are given up on (a fault in the record)
DEAD_SPINUP_S = 3.0  # ... this soon once the board reports a dead ESC


ROTATION_TOL = 1e-6
"""How far from orthonormal (‖RᵀR − I‖_F, and |det R − 1|) a retarget's matrix may be: a user's script's
rotation built from rounded or single-precision numbers is taken; a NaN, a reflection or a scaled matrix
is not."""


def _not_a_rotation(R: object) -> str | None:
    """Why ``R`` is not a rotation matrix (3, 3) within :data:`ROTATION_TOL`, or None."""
    try:
        m = np.asarray(R, dtype=float)
    except (TypeError, ValueError) as exc:
        return f"not numbers ({exc})"
    if m.shape != (3, 3):
        return f"shape {m.shape}, not (3, 3)"
    if not np.isfinite(m).all():
        return "it holds a value that is not finite"
    if not so3.is_rotation(m, ROTATION_TOL):
        return f"not orthonormal with determinant +1 within {ROTATION_TOL:g}"
    return None


class Phase(enum.IntEnum):
    """The run's phase, as ``telemetry.csv``'s ``phase`` column holds it (see the module docstring)."""

    WARMUP = 0
    SLEW = 1
    HOLD = 2
    SUSPENDED = 3  # disarmed by the operator: no reference, no requirement clock, until the operator's Arm


class RunPhases:
    """The phases of one run of ``scenario`` (see the module docstring). ``hold``: the target is the
    attitude estimated at the end of the warm-up, not the scenario's. Transitions are written to
    ``events``; a rotor given up on is a note in ``journal``."""

    def __init__(self, scenario: Scenario, events: EventLog, journal: FaultJournal, hold: bool) -> None:
        self.scenario = scenario
        self.events = events
        self.journal = journal
        self.hold = hold
        self.nominal_rotor_speed = scenario.spacecraft.nominal_rotor_speed  # rad/s
        self.phase = Phase.WARMUP
        self.still_since: float | None = None  # the still window began at (host s; this warm-up)
        self.spinup_since: float | None = None  # the spin-up began at (host s; this warm-up)
        self.spun_since: float | None = None  # the rotors within SPUN_UP of nominal since (this warm-up)
        self.bias_samples: list[Array] = []  # raw gyro samples (3,) rad/s over the still window's second half
        self.collecting_bias = False  # the first still window's second half is on: gyro samples are kept
        self.gyro_bias = np.zeros(3)  # rad/s, from the still window: the estimator's bias from then on
        self.target: Array | None = None if hold else scenario.slew.R_target  # (3, 3) body → inertial
        self.target9: so3.Mat9 | None = None if self.target is None else so3.mat9(self.target)
        self.slew: EigenaxisSlew | None = None
        self.slew_start: float | None = None  # the scenario's slew started at (host s)
        self.need_still = True  # the warm-up's still window is due (the first one, or the phone's back)
        # the first still window runs before the spin-up (the rotors at rest); taken to be so until the
        # first tick with the board in hand measures them, so no tick before it commands nominal speed
        self._rest_still = True
        self._resume_still = False  # the phone went away while suspended: the Arm's warm-up has its window
        self._given_up: set[int] = set()  # units whose rotor never reached speed: not waited for again
        self.suspended_since: float | None = None  # the operator's Disarm suspended the run at (host s)
        self.suspended_s = 0.0  # closed suspensions in all (host s): the run's time limit moves by this
        self.suspended_after_slew_s = 0.0  # ... of it after the slew's start: the requirement clock's

    # ------------------------------------------------------------------ what the phases say
    @property
    def first_warmup(self) -> bool:
        """Whether the scenario's slew is still to come (the first warm-up is not over)."""
        return self.slew_start is None

    @property
    def resting(self) -> bool:
        """The first warm-up's still window, before the spin-up: the rotors are held stopped."""
        return self._rest_still and self.spinup_since is None

    def time_is_up(self, t: float, duration_s: float) -> bool:
        """Whether the run has had its ``duration_s`` (s) from the slew's start at ``t``, the operator's
        suspensions after it not counted (never while suspended or before the slew)."""
        if self.suspended_since is not None or self.slew_start is None:
            return False
        return t - self.slew_start - self.suspended_after_slew_s >= duration_s - 1e-9

    # ------------------------------------------------------------------ warm-up → slew
    def warm_up(
        self,
        t: float,
        rotor: Array,
        *,
        ready: bool,
        phone_fresh: bool,
        attitude: Array | None,
        estimator: Estimator,
        esc_dead: bool,
    ) -> bool:
        """One control tick of the warm-up at ``t`` (s) with the rotors at ``rotor`` (n,) rad/s: the still
        window when due, spin-up (gimbals still), checks; then the slew (the scenario's, or after a
        recovery a new one to the target). True when it ends with a new slew (the control step starts
        afresh). ``ready``: the board is armed and no re-arm is pending; ``attitude`` (3, 3) the estimate
        (None before the estimator's first output); ``esc_dead``: the board reports a dead ESC.

        The first still window comes *before* the spin-up when the rotors are at rest: spun-up rotors on
        gimbal axes a few mrad off nominal turn the body, which a later window took for gyro bias
        (docs/montecarlo.md). A later one keeps the rotors spinning."""
        if not ready:
            return False
        nominal = self.nominal_rotor_speed
        first = self.first_warmup
        if first and self.need_still and self.spinup_since is None and self.still_since is None:
            self._rest_still = bool(np.all(np.abs(rotor) <= SPUN_UP * nominal))
        if self.resting:
            if not self._still_window(t, rotor, phone_fresh, attitude, estimator):
                return False
            self._rest_still = False
        if self.spinup_since is None:
            self.spinup_since = t
            self.events.write(t, "spin_up", nominal_rad_s=nominal)
        if self.still_since is None or not self.need_still:  # not during a still window once begun
            if not self._spun_up(t, rotor, esc_dead):
                return False
            if self.spun_since is None:
                self.spun_since = t
        if self.need_still and not self._still_window(t, rotor, phone_fresh, attitude, estimator):
            return False
        if attitude is None or not phone_fresh:
            return False
        if not first:
            self._resume(t, attitude)
            return True
        if self.spun_since is not None and t - self.spun_since >= ROTOR_SETTLE_S:
            self._start_slew(t, attitude, estimator)
            return True
        return False

    def add_bias_sample(self, gyro: Array) -> None:
        """A raw gyro sample (3,) rad/s of the still window's second half (while :attr:`collecting_bias`)."""
        self.bias_samples.append(gyro)

    def _spun_up(self, t: float, rotor: Array, esc_dead: bool) -> bool:
        """Whether every rotor the host still counts on is within :data:`SPUN_UP` of nominal. A rotor
        that does not get there within :data:`MAX_SPINUP_S` of the spin-up (:data:`DEAD_SPINUP_S` once the
        board reports a dead ESC) is given up on — a fault in the record (``spin_up_failed``) — and the
        host goes on with the array it has (steering degrades gracefully; the run's requirement says
        why it was missed), rather than end the run."""
        nominal = self.nominal_rotor_speed
        off = np.abs(rotor - nominal) > SPUN_UP * nominal
        off[list(self._given_up)] = False
        if not off.any():
            return True
        assert self.spinup_since is not None
        waited = t - self.spinup_since
        if waited > MAX_SPINUP_S or (esc_dead and waited > DEAD_SPINUP_S):
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

    def _still_window(
        self, t: float, rotor: Array, phone_fresh: bool, attitude: Array | None, estimator: Estimator
    ) -> bool:
        """The still window (``warmup_s``; the first one's second half gives the gyro bias): True once it
        is over (``need_still`` cleared). It is the estimator's: it starts when the phone streams, and it
        waits for the estimator's first output."""
        if self.still_since is None:
            if not phone_fresh:
                return False
            self.still_since = t
            self.events.write(t, "still_window", rotor_rad_s=rotor.round(1).tolist())
        if attitude is None or not phone_fresh:
            return False
        warmup_s = self.scenario.loop.warmup_s
        first = self.first_warmup
        self.collecting_bias = first and t - self.still_since >= 0.5 * warmup_s
        if t - self.still_since < warmup_s:
            return False
        self.collecting_bias = False
        self.need_still = False
        if first and self.scenario.loop.calibrate_rate_bias and self.bias_samples:
            self.gyro_bias = np.mean(self.bias_samples, axis=0)
            estimator.set_gyro_bias(self.gyro_bias)
        return True

    def _start_slew(self, t: float, attitude: Array, estimator: Estimator) -> None:
        """The end of the first warm-up: the scenario's slew from the attitude estimated now."""
        online = estimator.gyro_bias  # what the estimator had found by itself
        # from now on the spacecraft moves under control: a slew's slow end or a hold turns steadily below
        # the rest detector's rate bound, and learning that as bias would be wrong (4.8° off after a 90°
        # slew); the variational bias law keeps correcting the estimate in motion
        estimator.set_rest_learning(False)
        R_hat = np.asarray(attitude)
        sl = self.scenario.slew
        self.target = R_hat.copy() if self.hold else sl.R_target
        self.target9 = so3.mat9(self.target)
        self.slew = EigenaxisSlew.within_limits(R_hat, self.target, sl.max_rate, sl.max_accel, start_s=t)
        self.slew_start = t
        self.phase = Phase.SLEW
        self.events.write(
            t,
            "slew_start",
            angle_deg=math.degrees(so3.principal_angle(R_hat.T @ self.target)),
            slew_s=self.slew.duration_s,
            gyro_bias=self.gyro_bias.tolist(),
            gyro_bias_online=online.tolist(),
        )

    def _resume(self, t: float, attitude: Array) -> None:
        """The end of a recovery: a new slew from the attitude estimated now to the target."""
        assert self.target is not None
        R_hat = np.asarray(attitude)
        sl = self.scenario.slew
        self.slew = EigenaxisSlew.within_limits(R_hat, self.target, sl.max_rate, sl.max_accel, start_s=t)
        self.phase = Phase.SLEW
        self.events.write(
            t,
            "resume",
            angle_deg=math.degrees(so3.principal_angle(R_hat.T @ self.target)),
            slew_s=self.slew.duration_s,
        )

    # ------------------------------------------------------------------ slew → hold, retargeting
    def finish_slew(self, t: float) -> None:
        """The slew's time is over at ``t`` (s): the reference stays at the target from now on."""
        assert self.slew is not None
        if self.phase is Phase.SLEW and t >= self.slew.start_s + self.slew.duration_s:
            self.phase = Phase.HOLD
            self.events.write(t, "slew_end")

    def retarget(self, t: float, attitude: Array | None, R_target: Array | None) -> str | None:
        """A new target from outside the loop (the ground station's slew or hold): an eigenaxis slew from
        ``attitude`` (3, 3), the attitude estimated now, to ``R_target`` (3, 3), body → inertial (None:
        hold ``attitude``), within the scenario's rate and acceleration limits, from ``t`` (s). The run
        still ends ``duration_s`` after the scenario's slew started. Returns why it was refused, or None:
        during the first warm-up there is no estimate to start from and the scenario's own slew is still
        to come. During a recovery's warm-up (or while the operator has the run suspended) the target is
        taken and the slew to it starts when the recovery ends (planned anew from the attitude estimated
        then: the operator's record says ``deferred`` until then, :mod:`hil.runtime.operator`)."""
        if self.slew_start is None or attitude is None:
            return "the warm-up is not over (the scenario's slew has not started)"
        if R_target is not None:
            not_rotation = _not_a_rotation(R_target)
            if not_rotation is not None:  # a NaN target was taken, and its NaN setpoints ended the run later
                return f"the target is not a rotation: {not_rotation}"
        R_hat = np.asarray(attitude)
        self.target = R_hat.copy() if R_target is None else np.asarray(R_target, dtype=float)
        self.target9 = so3.mat9(self.target)
        sl = self.scenario.slew
        self.slew = EigenaxisSlew.within_limits(R_hat, self.target, sl.max_rate, sl.max_accel, start_s=t)
        if self.phase in (Phase.SLEW, Phase.HOLD):
            self.phase = Phase.SLEW
        return None

    # ------------------------------------------------------------------ back to the warm-up
    def restart_warmup(self, t: float, why: str, still: bool, force: bool = False) -> None:
        """The board left the state the host commanded (failsafe, reset, link loss, reconnect) or the
        phone went away: back to the warm-up — spin-up and checks; the still window too if ``still`` (the
        phone), or if the first warm-up was not over (its bias window then starts again). While the
        operator has the run suspended it stays so; the warm-up the operator's Arm starts then includes
        the still window if the phone went away meanwhile. ``force``: restart even a warm-up with nothing
        under way (the operator's Arm)."""
        if self.phase is Phase.SUSPENDED:
            self._resume_still = self._resume_still or still
            self.events.write(t, "fault_while_suspended", reason=why)
            return
        started = self.spinup_since is not None or self.still_since is not None
        if not force and self.phase is Phase.WARMUP and not started and not (still and not self.need_still):
            return  # nothing under way to restart
        first = self.first_warmup
        self.phase = Phase.WARMUP
        self.spinup_since = self.still_since = self.spun_since = None
        self.need_still = self.need_still or still or first
        if first:
            self.bias_samples.clear()
        self.collecting_bias = False
        self.events.write(t, "warmup_restart" if first else "recovery_start", reason=why)

    # ------------------------------------------------------------------ the operator's suspension
    def suspend(self, t: float, origin: str) -> None:
        """The operator's Disarm at ``t`` (s) from ``origin``: the run is suspended — no reference (the
        slew does not go on without the actuators), no setpoints, no requirement clock — until
        :meth:`end_suspension`. Already suspended: nothing changes."""
        if self.suspended_since is not None:
            return
        self.suspended_since = t
        self._resume_still = False
        self.phase = Phase.SUSPENDED
        self.events.write(t, "suspended", by=origin)

    def end_suspension(self, t: float, origin: str) -> None:
        """The operator's Arm at ``t`` (s) from ``origin``: a suspension ends — its time moves the run's
        time limit (and, after the slew's start, the requirement clock) — and the warm-up runs again
        (spin-up, checks; the still window too if the phone went away meanwhile), then a new slew from
        the attitude estimated then to the target (the first warm-up starts over if the scenario's slew
        had not started). Not suspended: nothing changes."""
        since = self.suspended_since
        if since is None:
            return
        self.suspended_since = None
        self.suspended_s += t - since
        if self.slew_start is not None:
            self.suspended_after_slew_s += t - max(since, self.slew_start)
        self.phase = Phase.WARMUP
        self.restart_warmup(t, "operator_arm", still=self._resume_still, force=True)
        self.events.write(t, "suspension_end", by=origin, suspended_s=t - since)
