"""ESC/motor and gimbal-servo response of one VSCMG unit, driven by pulse widths.

The rotor's ESC (:class:`firmware_sim.board.esc.EmulatedEsc`: factory endpoints, endpoint programming, arming
at minimum) drives the motor only while it is powered and armed. Its steady no-load speed comes from one
of two sources:

* **ideal unit** (``truth`` None, the default): the unit's calibration map
  (``UnitCalibration.rotor_speed(pulse_us, battery_v)``, so a sagging battery means a slower rotor): the
  unit is exactly what the board's calibration says (its ESC's endpoints are not consulted);
* **bench unit** (``truth`` an :class:`ActuatorTruth`): its own motor and servo models
  (``protocol.calibration.EscMotorModel``/``GimbalServoModel``, drawn per unit around the stated models),
  the motor's throttle taken between the endpoints the ESC has *learned*, so an ESC still at its factory
  endpoints behaves differently from one programmed to the board's, and a fit of bench sweeps has
  something real to recover.

The rotor follows its steady speed with a first-order lag (``time_constant_s`` spinning up,
``coast_time_constant_s`` spinning down: the ESC does not brake). The gimbal servo follows the rate or
angle its pulse stands for (the calibration's ``gimbal_value(pulse_us, mode)`` or the true servo's).
Integration is exact for a constant input over a step, so lockstep callers may take steps of any length.

In closed-loop emulation the world owns the dynamics: :meth:`UnitModel.override` replaces the internal
model with measured states (the board then only computes currents from them).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from protocol.calibration import EscMotorModel, GimbalServoModel
from protocol.compiled import fast_constructor
from protocol.errors import ConfigError
from protocol.messages import GIMBAL_ANGLE_LIMIT, GIMBAL_RATE_LIMIT, ROTOR_SPEED_LIMIT, GimbalMode, UnitState

from .config import BoardConfig, GimbalParams, MotorParams
from .esc import EmulatedEsc, EscParams
from .volts import TenMillivolts

_new_unit_state = fast_constructor(UnitState)
"""``UnitState`` built by its slots (gimbal angle, gimbal rate, rotor speed): 0.31 µs against 0.96 µs for the
frozen dataclass's keyword ``__init__``; four in every ``Telemetry`` (:meth:`UnitModel.state`)."""


@dataclass(frozen=True)
class ActuatorTruth:
    """A bench unit's true actuators: ``motor`` (its ``low_us``/``high_us`` are replaced by the endpoints
    its ESC has learned) and the gimbal ``servo``."""

    motor: EscMotorModel
    servo: GimbalServoModel


class UnitModel:
    """Rotor speed (rad/s), gimbal angle (rad) and rate (rad/s) of one unit, and the power it draws.

    ``calibration`` is the unit's ``protocol.calibration.UnitCalibration``; ``truth`` its true actuators
    (None: an ideal unit, see the module docstring); ``esc`` its rotor ESC's programming behaviour.
    ``esc_connected`` is the operator's side of the ESC's supply (the board's switch is the other)."""

    def __init__(
        self,
        motor: MotorParams,
        gimbal: GimbalParams,
        calibration: Any,
        truth: ActuatorTruth | None = None,
        esc: EscParams | None = None,
    ) -> None:
        self.motor = motor
        self.gimbal = gimbal
        self.truth = truth
        self.esc = EmulatedEsc(esc if esc is not None else EscParams())
        self.esc_connected = True
        self._calibration = calibration
        self._cache: dict[tuple[str, float, Any], float] = {}
        self._volts = TenMillivolts()  # round(v, 2), the cache's voltage key
        self._true_motor: EscMotorModel | None = None
        self.rotor_speed = 0.0
        self.rotor_accel = 0.0
        self.gimbal_angle = 0.0
        self.gimbal_rate = 0.0
        self.gimbal_mode = GimbalMode.RATE
        self.rotor_dead = False
        self.gimbal_dead = False
        self.rotor_driven = False  # the ESC receives pulses and is alive
        self.gimbal_driven = False
        self._external_t: float | None = None  # when the world last handed a state over (None: the model's)

    @property
    def calibration(self) -> Any:
        return self._calibration

    @calibration.setter
    def calibration(self, cal: Any) -> None:
        self._calibration = cal
        self._cache.clear()

    def rotor_speed_for(self, pulse_us: float, battery_v: float) -> float:
        """Steady no-load speed (rad/s) of ``pulse_us`` at ``battery_v`` (cached per 10 mV)."""
        v = self._volts(battery_v)
        key = ("r", pulse_us, v)
        hit = self._cache.get(key)
        if hit is None:
            hit = float(self._calibration.rotor_speed(float(pulse_us), v).value)
            self._remember(key, hit)
        return hit

    def gimbal_value_for(self, pulse_us: float, mode: GimbalMode) -> float:
        """Gimbal rate (rad/s) or angle (rad) that ``pulse_us`` stands for in ``mode`` (cached)."""
        key = ("g", pulse_us, mode)
        hit = self._cache.get(key)
        if hit is None:
            hit = float(self._calibration.gimbal_value(float(pulse_us), mode).value)
            self._remember(key, hit)
        return hit

    def true_rotor_speed_for(self, pulse_us: float, battery_v: float) -> float:
        """Steady no-load speed (rad/s) the motor really reaches on ``pulse_us`` through its ESC (which
        must be armed): the calibration map for an ideal unit, else the true motor between the ESC's
        learned endpoints."""
        if self.truth is None:
            return self.rotor_speed_for(pulse_us, battery_v)
        motor = self._true_motor
        if motor is None or (motor.low_us, motor.high_us) != (self.esc.low_us, self.esc.high_us):
            motor = self._true_motor = dataclasses.replace(
                self.truth.motor, low_us=self.esc.low_us, high_us=self.esc.high_us
            )
        return motor.speed(float(pulse_us), battery_v)

    def true_gimbal_value_for(self, pulse_us: float, mode: GimbalMode) -> float:
        """The rate (rad/s) or angle (rad) the servo really goes to on ``pulse_us``."""
        if self.truth is None:
            return self.gimbal_value_for(pulse_us, mode)
        servo = self.truth.servo
        return servo.rate(float(pulse_us)) if mode == GimbalMode.RATE else servo.angle(float(pulse_us))

    def _remember(self, key: tuple[str, float, Any], value: float) -> None:
        if len(self._cache) > 4096:
            self._cache.clear()
        self._cache[key] = value

    # ------------------------------------------------------------------ closed-loop hook
    def override(self, state: UnitState | None, t: float, rotor_accel: float | None = None) -> None:
        """Use measured ``state`` at ``t`` (s) instead of the internal model (None: back to the model).
        ``rotor_accel`` (rad/s²; the power draw's acceleration term): as measured with the state, or by
        default the speed's change since the last state handed over (over whatever span that was)."""
        if state is None:
            self._external_t = None
            return
        self.follow(state.gimbal_angle, state.gimbal_rate, state.rotor_speed, t, rotor_accel)

    def follow(
        self,
        gimbal_angle: float,
        gimbal_rate: float,
        rotor_speed: float,
        t: float,
        rotor_accel: float | None = None,
    ) -> None:
        """:meth:`override` with the measured state as plain floats (rad, rad/s, rad/s): what the world
        hands over at every board event, with no :class:`UnitState` built for it (telemetry builds one
        from them, :meth:`state`)."""
        prev_t = self._external_t
        if rotor_accel is not None:
            self.rotor_accel = rotor_accel
        elif prev_t is not None and t > prev_t:  # the model does not move the speed while it is followed
            self.rotor_accel = (rotor_speed - self.rotor_speed) / (t - prev_t)
        self._external_t = t
        self.rotor_speed = rotor_speed
        self.gimbal_angle = gimbal_angle
        self.gimbal_rate = gimbal_rate

    @property
    def external(self) -> bool:
        return self._external_t is not None

    # ------------------------------------------------------------------ dynamics
    def step(
        self,
        now: float,
        dt: float,
        gimbal_us: float | None,
        rotor_us: float | None,
        supply_on: bool,
        battery_v: float,
    ) -> None:
        """The unit's hardware at ``now`` (s), ``dt`` s after the last step: its ESC sees ``rotor_us``
        (None: no pulse, or a dead ESC) powered if the board's switch (``supply_on``) and the operator
        (:attr:`esc_connected`) both let it, then the motors move over ``dt`` with the pulses held
        constant (exact for constant inputs; a unit the world drives, :meth:`follow`, does not move)."""
        esc = self.esc
        esc.update(now, None if self.rotor_dead else rotor_us, supply_on and self.esc_connected)
        self.rotor_driven = rotor_us is not None and not self.rotor_dead and esc.powered
        self.gimbal_driven = gimbal_us is not None and not self.gimbal_dead
        if dt <= 0.0 or self._external_t is not None:
            return
        self._advance_rotor(dt, rotor_us, battery_v)
        self._advance_gimbal(dt, gimbal_us)

    def steady_rotor_speed(self, rotor_us: float | None, battery_v: float) -> float:
        """The no-load speed the ESC drives towards (0 without pulses, with a dead ESC, or an ESC that is
        unpowered, unarmed or being programmed)."""
        pulse = self.esc.throttle_pulse(rotor_us)
        if pulse is None or self.rotor_dead:
            return 0.0
        return self.true_rotor_speed_for(pulse, battery_v)

    def _advance_rotor(self, dt: float, rotor_us: float | None, battery_v: float) -> None:
        m = self.motor
        target = self.steady_rotor_speed(rotor_us, battery_v)
        w0 = self.rotor_speed
        tau = m.time_constant_s if (target > w0 and self.rotor_driven) else m.coast_time_constant_s
        decay = math.exp(-dt / tau)
        w = target + (w0 - target) * decay
        self.rotor_speed = w
        self.rotor_accel = (target - w) / tau

    def _advance_gimbal(self, dt: float, gimbal_us: float | None) -> None:
        g = self.gimbal
        tau = g.time_constant_s
        if not self.gimbal_driven or gimbal_us is None:
            target_rate = 0.0
        elif self.gimbal_mode == GimbalMode.RATE:
            target_rate = self.true_gimbal_value_for(gimbal_us, GimbalMode.RATE)
            if self.truth is None:  # a bench servo's top rate is its own
                target_rate = max(min(target_rate, g.max_rate_rad_s), -g.max_rate_rad_s)
        else:
            self._advance_gimbal_angle(dt, self.true_gimbal_value_for(gimbal_us, GimbalMode.ANGLE))
            return
        r0 = self.gimbal_rate
        decay = math.exp(-dt / tau)
        self.gimbal_rate = target_rate + (r0 - target_rate) * decay
        self.gimbal_angle += target_rate * dt + (r0 - target_rate) * tau * (1.0 - decay)

    def _advance_gimbal_angle(self, dt: float, target: float) -> None:
        """Position servo: rate = error / τ, limited to ±max rate, in sub-steps of at most τ/4."""
        g = self.gimbal
        n = max(1, math.ceil(dt / (g.time_constant_s / 4.0)))
        h = dt / n
        angle = self.gimbal_angle
        rate = 0.0
        for _ in range(n):
            err = target - angle
            rate = max(min(err / g.time_constant_s, g.max_rate_rad_s), -g.max_rate_rad_s)
            step = rate * h
            angle = target if abs(step) >= abs(err) else angle + step
        self.gimbal_angle = angle
        self.gimbal_rate = rate

    # ------------------------------------------------------------------ loads
    def rotor_power_w(self, battery_v: float) -> float:
        """Electrical power the rotor's ESC draws from the battery (W)."""
        if not self.rotor_driven:
            return 0.0
        return esc_power_w(self.motor, self.rotor_speed, self.rotor_accel, battery_v)

    def gimbal_current_a(self) -> float:
        """Current the gimbal servo draws from the UBEC rail (A)."""
        if not self.gimbal_driven:
            return 0.0
        return self.gimbal.idle_current_a + self.gimbal.current_per_rad_s_a * abs(self.gimbal_rate)

    def state(self) -> UnitState:
        """The unit's state clamped to the wire's ranges (for Telemetry), built by the message's slots:
        :meth:`state_reference` by keyword is the tests' oracle."""
        return _new_unit_state(
            _clamp(self.gimbal_angle, GIMBAL_ANGLE_LIMIT),
            _clamp(self.gimbal_rate, GIMBAL_RATE_LIMIT),
            _clamp(self.rotor_speed, ROTOR_SPEED_LIMIT),
        )

    def state_reference(self) -> UnitState:
        """:meth:`state` through ``UnitState``'s keyword constructor: the oracle of
        ``tests/test_hunt9_e_board_messages.py``."""
        return UnitState(
            gimbal_angle=_clamp(self.gimbal_angle, GIMBAL_ANGLE_LIMIT),
            gimbal_rate=_clamp(self.gimbal_rate, GIMBAL_RATE_LIMIT),
            rotor_speed=_clamp(self.rotor_speed, ROTOR_SPEED_LIMIT),
        )


def _clamp(x: float, limit: float) -> float:
    if not math.isfinite(x):
        return 0.0
    if x > limit:  # max(min(x, limit), -limit) spelt out: three per unit in every Telemetry
        return limit
    if x < -limit:
        return -limit
    return x


def bench_truths(cfg: BoardConfig) -> list[ActuatorTruth | None]:
    """Each unit's true actuators: None (ideal units) or drawn from ``cfg.unit_spread_seed``."""
    if cfg.unit_spread_seed is None:
        return [None] * cfg.n_units
    from hil.calibration.generate import bench_units  # the stated models' spread, only when asked for

    return [ActuatorTruth(u.motor, u.gimbal) for u in bench_units(cfg.n_units, cfg.unit_spread_seed)]


def follow_all(
    units: Sequence[UnitModel], values: Sequence[float], t: float, rotor_accel: Sequence[float]
) -> None:
    """Every unit follows the world's state at ``t`` (s): ``values`` holds the gimbal angles (rad), the
    gimbal rates (rad/s) and the rotor speeds (rad/s), ``len(units)`` of each one after the other (one row
    of the world's unit columns); ``rotor_accel`` (rad/s², one per unit) as :meth:`UnitModel.follow`."""
    n = len(units)
    if len(values) != 3 * n or len(rotor_accel) != n:
        raise ConfigError(
            f"{len(values)} values and {len(rotor_accel)} accelerations for {n} units", "follow_all"
        )
    # UnitModel.follow's body with its acceleration given, spelt out: this runs at every board event
    # (~15 000 times a default run), where a method call per unit was half its cost. An acceleration of
    # None (not measured) takes the method, which then works it out.
    for i, unit in enumerate(units):
        accel = rotor_accel[i]
        if accel is None:
            unit.follow(values[i], values[n + i], values[2 * n + i], t, None)
            continue
        unit.rotor_accel = accel
        unit._external_t = t
        unit.rotor_speed = values[2 * n + i]
        unit.gimbal_angle = values[i]
        unit.gimbal_rate = values[n + i]


def esc_power_w(m: MotorParams, speed: float, accel_rad_s2: float, battery_v: float) -> float:
    """Electrical power (W) an ESC draws from the battery at ``battery_v`` (V) for its motor ``m`` (a
    motor model: rated power and speed, rotor inertia, efficiency, idle current) turning at ``speed``
    rad/s and speeding up at ``accel_rad_s2`` rad/s²: the air drag's cube law plus the power into the
    rotor's speed along its spin (slowing down returns nothing: the ESC does not brake), through the
    ESC's efficiency, plus its idle draw."""
    w = abs(speed)
    drag = m.rated_power_w * (w / m.rated_speed_rad_s) ** 3
    accel = m.inertia_kg_m2 * w * accel_rad_s2  # power into the rotor's speed along its spin
    if speed < 0.0:
        accel = -accel
    if accel < 0.0:  # slowing down returns nothing (the ESC does not brake)
        accel = 0.0
    return (drag + accel) / m.efficiency + m.idle_current_a * battery_v
