"""A closed-loop attitude simulation in lockstep time, built from the pieces the host and the emulator's
world use: the plant (:mod:`hil.vscmg`) at its own step (≤ 1 ms) with the motor servos
(:class:`hil.control.motor_loops.ServoModel`), and at the control rate an attitude source → controller →
steering
→ setpoint generator. Pure math: no clock, no I/O; one call runs a whole scenario as fast as the CPU allows.

Attitude sources (what the controller is told):

- :class:`TruthWithNoise`: the plant's attitude and rate with phone-grade noise (attitude white noise
  of an estimator's size; the gyroscope's white noise and residual bias from
  :class:`hil.simulation.phone.PhoneSpec`);
- :class:`EstimatorInTheLoop`: a simulated phone on the spacecraft (accelerometer, gyroscope and
  magnetometer at their own rates, jitter, noise and bias, sampled from the plant's true motion), merged
  with hold-last-sample (:class:`hil.estimation.multirate.Merger`) and run through the paper's estimator
  (:class:`hil.estimation.filter.AttitudeFilter`) — the host's path.

Telemetry (gimbal angles, rotor speeds) is read from the plant, as the board would report it.

Per run, :meth:`ClosedLoop.run_batch` also takes the run's *true* spacecraft (the controller and steering
keep the nominal one: a dispersed plant under a nominally tuned loop, as in a Monte Carlo campaign) and
link outages, each ``(start_s, duration_s)`` from the slew's start. During an outage the host's setpoints
and the board's telemetry are lost: the servos hold the last setpoint and the host computes from the last
telemetry it had. Once nothing has reached the board for ``LoopConfig.link_timeout_s`` its watchdog acts
as firmware_sim's board does: FAILSAFE, gimbals held (zero rate), rotor ESCs at the safe pulse (zero
throttle: the rotors coast down with the ESC's ``esc_coast_time_constant_s``). When the link is back the
host sees FAILSAFE at its next tick and re-arms (the board, armed, still drives zero commands), and its
setpoints reach the servos from the tick after; each episode is one failsafe event in the log.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil import so3
from hil.control.attitude import AttitudeController, ControllerGains, EigenaxisSlew
from hil.control.motor_loops import ServoModel, ServoParams, SetpointGenerator, Setpoints
from hil.control.steering import SteeringParams, VscmgSteering
from hil.estimation.sensors import SensorKind
from hil.vscmg import Plant, PlantState, SpacecraftParams
from protocol.errors import ConfigError

Array = NDArray[np.float64]


# --------------------------------------------------------------------------- attitude sources
@dataclass(frozen=True)
class Measurement:
    """What the controller sees: attitude ``R`` (3, 3) body → inertial and body rate ``omega`` (3,) rad/s."""

    R: Array
    omega: Array


class AttitudeSource(Protocol):
    """Sees the true plant after every plant step (``observe``) and answers at control ticks (``measure``)."""

    def start(self, state: PlantState) -> None: ...

    def observe(self, state: PlantState) -> None: ...

    def measure(self) -> Measurement: ...


@runtime_checkable
class GyroCalibrated(Protocol):
    """A source that measures its raw gyroscope's bias over a still window and removes it itself, as the
    host does (``hil.runtime.host``: raw gyro samples of the still window's second half averaged and handed
    to the estimator): ``begin_gyro_bias()`` starts collecting, ``end_gyro_bias()`` applies and returns it."""

    def begin_gyro_bias(self) -> None: ...

    def end_gyro_bias(self) -> Array: ...


class TruthWithNoise:
    """The true attitude turned by white noise of ``attitude_noise_rad`` per axis (1σ), and the true rate
    plus the gyroscope's white noise (``rate_noise`` rad/s, 1σ) and a constant bias drawn once
    (``rate_bias`` rad/s, 1σ per axis). Defaults: 0.1° attitude noise, the Nexus-5 gyroscope figures."""

    def __init__(
        self,
        attitude_noise_rad: float = math.radians(0.1),
        rate_noise: float | None = None,
        rate_bias: float | None = None,
        seed: int = 0,
    ) -> None:
        from hil.simulation.phone import PhoneSpec

        gyr = PhoneSpec.nexus5().gyr
        self.attitude_noise = attitude_noise_rad
        self.rate_noise = gyr.noise if rate_noise is None else rate_noise
        self.rng = np.random.default_rng(seed)
        self.bias = self.rng.normal(0.0, gyr.bias if rate_bias is None else rate_bias, 3)
        self._state: PlantState | None = None

    def start(self, state: PlantState) -> None:
        self._state = state

    def observe(self, state: PlantState) -> None:
        self._state = state

    def measure(self) -> Measurement:
        assert self._state is not None, "start() first"
        s = self._state
        R = s.R[0] @ so3.exp(self.rng.normal(0.0, self.attitude_noise, 3))
        return Measurement(R, s.omega[0] + self.bias + self.rng.normal(0.0, self.rate_noise, 3))


class EstimatorInTheLoop:
    """A simulated phone fixed to the body (its frame = the body frame), read by the paper's estimator.

    Each sensor samples at its own rate with timestamp jitter, white noise and a constant bias
    (``spec``, default :meth:`PhoneSpec.nexus5`); the truth between plant steps is interpolated (geodesic
    for the attitude, linear for the rate). The inertial frame is ENU (a testbed on the ground: the
    accelerometer reads gravity, the magnetometer the local field). ``config`` is the estimator's
    :class:`hil.estimation.filter.FilterConfig` (default: the paper's)."""

    def __init__(self, spec: object | None = None, config: object | None = None, seed: int = 0) -> None:
        from hil.estimation.filter import AttitudeFilter, FilterConfig
        from hil.estimation.multirate import Merger
        from hil.simulation.phone import BodyPhone, PhoneSpec

        self.spec = spec if spec is not None else PhoneSpec.nexus5()
        self.filter = AttitudeFilter(config if config is not None else FilterConfig.paper())  # type: ignore[arg-type]
        self.merger = Merger()
        self.seed = seed
        self.phone: BodyPhone | None = None
        self.estimate: object | None = None
        self._prev: PlantState | None = None
        self.steps = 0
        self._gyro: list[tuple[float, float, float]] | None = None  # raw samples while calibrating
        self.gyro_bias: Array | None = None  # what the still window measured (None: not calibrated)

    def start(self, state: PlantState) -> None:
        from hil.simulation.phone import BodyPhone

        self._prev = state
        self.phone = BodyPhone(self.spec, self.seed, t0=state.t)  # type: ignore[arg-type]

    def observe(self, state: PlantState) -> None:
        prev = self._prev
        assert prev is not None and self.phone is not None, "start() first"
        self._prev = state
        if min(self.phone.next_t.values()) > state.t:  # no sensor samples in (prev.t, state.t]
            return
        samples = self.phone.sample(prev.t, prev.R[0], prev.omega[0], state.t, state.R[0], state.omega[0])
        for sample in samples:
            if self._gyro is not None and sample.kind is SensorKind.GYR:
                self._gyro.append(sample.xyz)
            for step in self.merger.push(sample):
                self.estimate = self.filter.step(step)
                self.steps += 1

    def begin_gyro_bias(self) -> None:
        """Start collecting raw gyroscope samples (the body is held still)."""
        self._gyro = []

    def end_gyro_bias(self) -> Array:
        """The mean raw gyro sample since :meth:`begin_gyro_bias` (3,) rad/s, subtracted by the estimator
        from every later sample (zero if none was collected)."""
        bias = np.mean(self._gyro, axis=0) if self._gyro else np.zeros(3)
        self._gyro = None
        self.filter.set_gyro_bias(bias)
        self.gyro_bias = bias
        return bias

    def measure(self) -> Measurement:
        if self.estimate is None:
            raise ConfigError(
                "the estimator has no estimate yet (no sensor step before the first tick)", "source"
            )
        est = self.estimate
        return Measurement(np.asarray(est.R), np.asarray(est.omega))  # type: ignore[attr-defined]


# --------------------------------------------------------------------------- the loop
@dataclass(frozen=True)
class LoopConfig:
    """Rates and the pieces' parameters: ``plant_step_s`` (≤ 1 ms), ``control_rate_hz`` (≤ the board's
    ``frame_rate_hz``), controller ``gains``, ``steering`` and ``servo`` parameters; ``warmup_s`` of
    holding still before the slew (the attitude source converges; the host waits for it the same way);
    ``calibrate_rate_bias``: the host's still-window gyro bias calibration over the warm-up's second half
    (a :class:`GyroCalibrated` source averages its raw gyro samples and removes the bias itself, as the
    host's estimator does; for others the measured rate is averaged at the ticks and subtracted from the
    rate the controller is given); ``link_timeout_s`` the
    board's link watchdog (firmware-sim's ``--link-timeout``, longer than a control period) and
    ``esc_coast_time_constant_s`` how a rotor slows once the failsafe cuts its throttle (the ESC does not
    brake; firmware_sim's motor default), both used only with link outages."""

    plant_step_s: float = 1e-3
    control_rate_hz: float = 50.0
    frame_rate_hz: float = 50.0
    gains: ControllerGains = field(default_factory=lambda: ControllerGains(0.7, 0.9))
    steering: SteeringParams = field(default_factory=lambda: SteeringParams(null_gain=0.5))
    servo: ServoParams = field(default_factory=ServoParams)
    warmup_s: float = 2.0
    calibrate_rate_bias: bool = True
    link_timeout_s: float = 0.25
    esc_coast_time_constant_s: float = 1.5

    def __post_init__(self) -> None:
        if not 0 < self.plant_step_s <= 1e-3:
            raise ConfigError(f"must be in (0, 1 ms], got {self.plant_step_s}", "LoopConfig.plant_step_s")
        if not (math.isfinite(self.link_timeout_s) and self.link_timeout_s > 1.0 / self.control_rate_hz):
            raise ConfigError(
                f"must be longer than a control period, got {self.link_timeout_s!r}",
                "LoopConfig.link_timeout_s",
            )
        if not (math.isfinite(self.esc_coast_time_constant_s) and self.esc_coast_time_constant_s > 0):
            raise ConfigError("must be positive", "LoopConfig.esc_coast_time_constant_s")
        steps = 1.0 / (self.control_rate_hz * self.plant_step_s)
        if abs(steps - round(steps)) > 1e-6:
            raise ConfigError("the control period must be a whole number of plant steps", "LoopConfig")


@dataclass(frozen=True)
class SlewScenario:
    """A rest-to-rest slew: from ``R0`` to ``R_target`` (3, 3) within ``max_rate`` rad/s and ``max_accel``
    rad/s², from gimbal angles ``gimbal_angle0`` (n,) rad and rotor speeds ``rotor_speed0`` (None: nominal),
    simulated for ``duration_s``."""

    name: str
    R0: Array
    R_target: Array
    duration_s: float = 40.0
    max_rate: float = 0.15
    max_accel: float = 0.025
    gimbal_angle0: ArrayLike = 0.0
    rotor_speed0: ArrayLike | None = None


@dataclass(frozen=True)
class ClosedLoopLog:
    """One run, sampled at the control rate (K ticks): ``t`` (K,) s from the slew's start; ``error_deg``
    (K,) true attitude error to the target; ``tracking_deg`` (K,) true error to the moving reference;
    ``estimate_error_deg`` (K,) of the source's attitude; ``gimbal_rate`` (K, n) true rad/s; ``rotor_speed``
    (K, n) rad/s; ``delta`` (K,); ``saturation`` (K,) :class:`hil.control.steering.Saturation` bits;
    ``torque_shortfall`` (K,) N m, required minus delivered torque; ``slew_end_s`` when the reference
    arrives; ``max_gimbal_rate`` the gimbal-rate limit (rad/s); ``link_up`` (K,) whether the tick's setpoint
    could reach the board, ``failsafe`` (K,) whether the board was not driving the host's setpoints
    (FAILSAFE, or re-armed and waiting for the next one), ``failsafe_events`` how many times its watchdog
    fired."""

    t: Array
    error_deg: Array
    tracking_deg: Array
    estimate_error_deg: Array
    gimbal_rate: Array
    rotor_speed: Array
    delta: Array
    saturation: Array
    torque_shortfall: Array
    slew_end_s: float
    max_gimbal_rate: float
    link_up: Array
    failsafe: Array
    failsafe_events: int

    def settle_time(self, tolerance_deg: float = 0.5) -> float:
        """The first time after which the error to the target stays within ``tolerance_deg`` (inf: never)."""
        outside = np.nonzero(self.error_deg > tolerance_deg)[0]
        if len(outside) == 0:
            return float(self.t[0])
        if outside[-1] == len(self.t) - 1:
            return math.inf
        return float(self.t[outside[-1] + 1])

    def summary(self, tolerance_deg: float = 0.5) -> dict[str, float]:
        """Settle time (s), final error (deg, mean of the last second), peak |gimbal rate| (rad/s) and
        minimum δ."""
        last = self.t >= self.t[-1] - 1.0
        return {
            "settle_time_s": self.settle_time(tolerance_deg),
            "final_error_deg": float(np.mean(self.error_deg[last])),
            "peak_gimbal_rate": float(np.max(np.abs(self.gimbal_rate))),
            "min_delta": float(np.min(self.delta)),
        }


Outage = tuple[float, float]
"""A link outage ``(start_s, duration_s)``, seconds from the slew's start."""


class _Link:
    """The host–board link of B runs with scheduled outages, and each board's link watchdog and failsafe
    (see the module docstring). Times are seconds from the slew's start."""

    ARMED, FAILSAFE, REARMED = 0, 1, 2

    def __init__(self, outages: Sequence[Sequence[Outage]], timeout_s: float) -> None:
        self.outages = [self._checked(i, o) for i, o in enumerate(outages)]
        self.timeout_s = timeout_s
        b = len(outages)
        self.any = any(self.outages)
        self.state = np.zeros(b, np.int64)
        self.last_rx = np.zeros(b)
        self.events = np.zeros(b, np.int64)

    @staticmethod
    def _checked(run: int, outages: Sequence[Outage]) -> list[Outage]:
        out = []
        for k, item in enumerate(outages):
            try:
                start, duration = (float(x) for x in item)
            except (TypeError, ValueError):
                raise ConfigError(
                    f"must be (start_s, duration_s), got {item!r}", f"link_outages[{run}][{k}]"
                ) from None
            if not (math.isfinite(start) and start >= 0 and math.isfinite(duration) and duration > 0):
                raise ConfigError(
                    f"needs start_s >= 0 and duration_s > 0, got {item!r}", f"link_outages[{run}][{k}]"
                )
            out.append((start, duration))
        return out

    def up(self, t: float) -> NDArray[np.bool_]:
        """(B,) whether frames get through at ``t``."""
        return np.array([not any(a <= t < a + d for a, d in o) for o in self.outages], dtype=bool)

    def tick(self, t: float, up: NDArray[np.bool_]) -> NDArray[np.bool_]:
        """The host's frame at tick ``t`` where the link is ``up``: re-arm a board in FAILSAFE, else the
        setpoint gets through. Returns (B,) where the board now takes the host's setpoints."""
        delivered = up & (self.state != self.FAILSAFE)
        self.state = np.where(up & (self.state == self.FAILSAFE), self.REARMED, self.state)
        self.state = np.where(delivered, self.ARMED, self.state)
        self.last_rx = np.where(up, t, self.last_rx)
        return delivered

    def watchdog(self, t: float) -> None:
        """Each board's link watchdog at ``t``: nothing received for longer than the timeout → FAILSAFE."""
        fired = (self.state != self.FAILSAFE) & (t - self.last_rx > self.timeout_s)
        if fired.any():
            self.state = np.where(fired, self.FAILSAFE, self.state)
            self.events += fired

    @property
    def failsafe(self) -> NDArray[np.bool_]:
        """(B,) boards not driving the host's setpoints (FAILSAFE, or re-armed without a setpoint yet)."""
        return self.state != self.ARMED


class _Drives:
    """The motor drives of B runs as the board commands them (a :data:`hil.vscmg.TorqueLaw`): each run's
    servos follow its last delivered setpoints; runs whose board is in failsafe hold their gimbals (zero
    rate) and let their rotors coast towards zero throttle."""

    def __init__(self, params: SpacecraftParams, config: LoopConfig, b: int, n: int) -> None:
        self.servo = ServoModel(params, config.servo)
        self.coasting = ServoModel(
            params, replace(config.servo, coast_time_constant_s=config.esc_coast_time_constant_s)
        )
        self.coasting.hold(Setpoints(np.zeros((1, n)), np.zeros((1, n)), np.zeros(1, bool)))
        self.gimbal_rate = np.zeros((b, n))
        self.rotor_speed = np.zeros((b, n))
        self.failsafe = np.zeros(b, bool)

    def hold(self, setpoints: Setpoints, runs: NDArray[np.bool_] | None = None) -> None:
        """Take ``setpoints`` (B, n) for the ``runs`` (B,) mask (None: every run)."""
        take = np.ones(len(self.failsafe), bool) if runs is None else runs
        self.gimbal_rate = np.where(take[:, None], setpoints.gimbal_rate, self.gimbal_rate)
        self.rotor_speed = np.where(take[:, None], setpoints.rotor_speed, self.rotor_speed)
        self.servo.hold(Setpoints(self.gimbal_rate, self.rotor_speed, setpoints.clamped))

    def __call__(
        self, t: float, gimbal_angle: Array, gimbal_rate: Array, rotor_rate: Array, gimbal_load: Array,
        rotor_load: Array,
    ) -> tuple[Array, Array]:  # fmt: skip
        args = (t, gimbal_angle, gimbal_rate, rotor_rate, gimbal_load, rotor_load)
        ug, us = self.servo(*args)
        if self.failsafe.any():
            cg, cs = self.coasting(*args)
            off = self.failsafe[:, None]
            ug, us = np.where(off, cg, ug), np.where(off, cs, us)
        return ug, us


class ClosedLoop:
    """Plant + servos at ``config.plant_step_s``; source → controller → steering → setpoints at the control
    rate. :meth:`run` plays one :class:`SlewScenario` and returns its :class:`ClosedLoopLog`;
    :meth:`run_batch` plays several at once on the plant's batch axis (one controller and source each).
    ``params`` is the spacecraft the controller and steering are built for (the nominal one)."""

    def __init__(self, params: SpacecraftParams, config: LoopConfig | None = None) -> None:
        self.params = params
        self.config = config or LoopConfig()
        self.plant = Plant(params)
        self.steering = VscmgSteering(params, self.config.steering)

    def run(
        self,
        scenario: SlewScenario,
        source: AttitudeSource,
        spacecraft: SpacecraftParams | None = None,
        link_outages: Sequence[Outage] = (),
    ) -> ClosedLoopLog:
        return self.run_batch(
            [scenario], [source], None if spacecraft is None else [spacecraft], [link_outages]
        )[0]

    def run_batch(
        self,
        scenarios: Sequence[SlewScenario],
        sources: Sequence[AttitudeSource],
        spacecraft: Sequence[SpacecraftParams] | None = None,
        link_outages: Sequence[Sequence[Outage]] | None = None,
    ) -> list[ClosedLoopLog]:
        """Every scenario for the longest one's duration (each log is cut to its own). ``spacecraft``: each
        run's true spacecraft (None: the nominal ``params``; same unit count, limits and nominal rotor
        speed); ``link_outages``: each run's outages ``(start_s, duration_s)`` from the slew's start."""
        b = len(scenarios)
        if len(sources) != b or not scenarios:
            raise ConfigError("need one attitude source per scenario", "ClosedLoop.run_batch")
        for name, given in (("spacecraft", spacecraft), ("link_outages", link_outages)):
            if given is not None and len(given) != b:
                raise ConfigError(
                    f"need one entry per scenario, got {len(given)}", f"ClosedLoop.run_batch.{name}"
                )
        cfg = self.config
        link = _Link([()] * b if link_outages is None else link_outages, cfg.link_timeout_s)
        plant = self.plant if spacecraft is None else Plant(spacecraft)
        nominal = self.params.nominal_rotor_speed
        R0 = np.stack([np.asarray(sc.R0, float) for sc in scenarios])
        gimbal0 = np.stack([np.broadcast_to(sc.gimbal_angle0, (plant.n,)) for sc in scenarios])
        rotor0 = np.stack(
            [
                np.broadcast_to(nominal if sc.rotor_speed0 is None else sc.rotor_speed0, (plant.n,))
                for sc in scenarios
            ]
        )
        state = plant.state(R=R0, gimbal_angle=gimbal0, rotor_rate=rotor0)
        # what the controller is told: the nominal spacecraft's inertia
        inertia = self.plant.locked_inertia(self.plant.state(R=R0, gimbal_angle=gimbal0, rotor_rate=rotor0))
        controllers = [AttitudeController(inertia[i], cfg.gains) for i in range(b)]
        setpoints = SetpointGenerator(self.params, cfg.control_rate_hz, cfg.frame_rate_hz)
        setpoints.reset(state.rotor_rate)
        drives = _Drives(self.params, cfg, b, plant.n)
        drives.hold(Setpoints(np.zeros_like(state.gimbal_rate), state.rotor_rate.copy(), np.zeros(b, bool)))
        runs = range(b)
        for i in runs:
            sources[i].start(plant.select(state, i))

        def advance(state: PlantState, steps: int, calibrate: list[list[Array]] | None = None) -> PlantState:
            for k in range(steps):
                state = plant.step(state, cfg.plant_step_s, drives)
                for i in runs:
                    sources[i].observe(plant.select(state, i))
                    if calibrate is not None and (k + 1) % per_tick == 0 and not self_calibrated[i]:
                        calibrate[i].append(sources[i].measure().omega)
                if link.any:
                    link.watchdog(state.t - t0)
                    drives.failsafe = link.failsafe
            return state

        # Warm-up, held still: the sources converge; over its second half the rate bias is measured (from
        # the raw gyro by sources that calibrate themselves, else from the measured rate at the ticks)
        per_tick = int(round(1.0 / (cfg.control_rate_hz * cfg.plant_step_s)))
        self_calibrated = [cfg.calibrate_rate_bias and isinstance(src, GyroCalibrated) for src in sources]
        still: list[list[Array]] = [[] for _ in runs]
        t0 = math.inf  # the watchdog starts with the slew (outages start at or after it)
        warmup = int(round(cfg.warmup_s / cfg.plant_step_s))
        state = advance(state, warmup // 2)
        for i in runs:
            if self_calibrated[i]:
                sources[i].begin_gyro_bias()  # type: ignore[attr-defined]
        state = advance(state, warmup - warmup // 2, still if cfg.calibrate_rate_bias else None)
        for i in runs:
            if self_calibrated[i]:
                sources[i].end_gyro_bias()  # type: ignore[attr-defined]
        bias = [np.mean(r, axis=0) if r else np.zeros(3) for r in still]
        t0 = state.t
        slews = [
            EigenaxisSlew.within_limits(sc.R0, sc.R_target, sc.max_rate, sc.max_accel, t0) for sc in scenarios
        ]
        rows: list[list[tuple]] = [[] for _ in runs]
        dt = 1.0 / cfg.control_rate_hz
        seen_gimbal, seen_rotor = state.gimbal_angle, state.rotor_rate  # the host's last telemetry
        for k in range(int(math.ceil(max(sc.duration_s for sc in scenarios) * cfg.control_rate_hz))):
            t, tick_s = state.t, k * dt  # tick_s: the tick's time from the slew's start, without drift
            up = link.up(tick_s)
            seen_gimbal = np.where(up[:, None], state.gimbal_angle, seen_gimbal)
            seen_rotor = np.where(up[:, None], state.rotor_rate, seen_rotor)
            h = self.steering.momentum(seen_gimbal, seen_rotor)
            meas = [sources[i].measure() for i in runs]
            refs = [slews[i].at(t) for i in runs]
            outs = [
                controllers[i].update(meas[i].R, meas[i].omega - bias[i], refs[i], dt, h[i]) for i in runs
            ]
            cmd = self.steering.solve(np.stack([o.torque for o in outs]), seen_gimbal, seen_rotor, dt)
            sp = setpoints.update(cmd, seen_rotor)
            if link.any:
                drives.hold(sp, link.tick(tick_s, up))
                drives.failsafe = link.failsafe
            else:
                drives.hold(sp)
            for i in runs:
                R = state.R[i]
                rows[i].append(
                    (
                        t - t0,
                        so3.angle_between(R, scenarios[i].R_target),
                        so3.angle_between(R, refs[i].R),
                        so3.angle_between(R, meas[i].R),
                        state.gimbal_rate[i].copy(),
                        state.rotor_rate[i].copy(),
                        float(cmd.delta[i]),
                        int(cmd.saturation[i]),
                        float(np.linalg.norm(outs[i].torque - cmd.torque[i])),
                        bool(up[i]),
                        bool(drives.failsafe[i]),
                    )
                )
            state = advance(state, per_tick)
        return [
            self._log(rows[i], scenarios[i].duration_s, slews[i].duration_s, int(link.events[i]))
            for i in runs
        ]

    def _log(
        self, rows: list[tuple], duration_s: float, slew_s: float, failsafe_events: int
    ) -> ClosedLoopLog:
        cols = list(zip(*rows[: int(math.ceil(duration_s * self.config.control_rate_hz))], strict=True))
        return ClosedLoopLog(
            t=np.array(cols[0]),
            error_deg=np.degrees(cols[1]),
            tracking_deg=np.degrees(cols[2]),
            estimate_error_deg=np.degrees(cols[3]),
            gimbal_rate=np.array(cols[4]),
            rotor_speed=np.array(cols[5]),
            delta=np.array(cols[6]),
            saturation=np.array(cols[7]),
            torque_shortfall=np.array(cols[8]),
            slew_end_s=slew_s,
            max_gimbal_rate=self.params.limits.max_gimbal_rate,
            link_up=np.array(cols[9], dtype=bool),
            failsafe=np.array(cols[10], dtype=bool),
            failsafe_events=failsafe_events,
        )


# --------------------------------------------------------------------------- the acceptance scenarios
SINGULAR_GIMBALS = np.radians([90.0, -90.0, 90.0, -90.0])
"""A zero-momentum CMG singularity of the 4-unit pyramid (spin axes as in :func:`hil.vscmg.pyramid`):
the transverse axes span no torque about body z."""


def slew_90deg(duration_s: float = 40.0) -> SlewScenario:
    """90° rest-to-rest about a skewed axis, from the zero-momentum gimbal set (all zero)."""
    axis = np.array([1.0, 2.0, 2.0]) / 3.0
    return SlewScenario("90deg", np.eye(3), so3.exp(math.pi / 2 * axis), duration_s)


def slew_through_singularity(duration_s: float = 40.0) -> SlewScenario:
    """60° about body z starting 2° off the singular gimbal set :data:`SINGULAR_GIMBALS`, whose
    singular direction is z: a pure CMG pseudo-inverse would ask for unbounded gimbal rates."""
    return SlewScenario(
        "singular",
        np.eye(3),
        so3.exp([0.0, 0.0, math.radians(60.0)]),
        duration_s,
        gimbal_angle0=SINGULAR_GIMBALS + np.radians([2.0, -2.0, 2.0, -2.0]),
    )
