"""Parameters of the emulated board: one frozen dataclass per part, all in SI units unless a name says
otherwise (``_us`` microseconds, ``_mah`` milliamp-hours, ``_v_cell`` volts per battery cell).

``BoardConfig.validate()`` checks every value and raises :class:`ConfigError` naming the field
(``BoardConfig.power.battery.cells``), so a bad CLI option or config file never reaches the main loop.
The defaults describe the paper's board: an ADK (ATmega2560) driving four VSCMG units (gimbal servo +
rotor ESC each) from a 3S LiPo, with a 5 V UBEC for the logic and the gimbal servos.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

from protocol.errors import ConfigError
from protocol.messages import MAX_UNITS, PULSE_MAX_US, PULSE_MIN_US
from protocol.pulse_widths import FINE_PER_US, FRACTION_BITS, TICK_US

from .esc import EscParams

# LiPo open-circuit voltage per cell against state of charge (0..1), a typical discharge curve.
LIPO_OCV_CURVE: tuple[tuple[float, float], ...] = (
    (0.00, 3.00),
    (0.05, 3.45),
    (0.10, 3.68),
    (0.20, 3.74),
    (0.30, 3.77),
    (0.40, 3.79),
    (0.50, 3.82),
    (0.60, 3.87),
    (0.70, 3.92),
    (0.80, 3.98),
    (0.90, 4.08),
    (1.00, 4.20),
)


@dataclass(frozen=True)
class Identity:
    """The AOA accessory identity strings the board answers ``Hello`` with (see ``HelloReply``)."""

    manufacturer: str = "vscmg-hil"
    model: str = "ADK-VSCMG"
    description: str = "Emulated ADK board (firmware_sim)"
    version: str = "1.0"
    uri: str = "https://example.invalid/vscmg-hil"
    serial: str = "SIM0001"
    firmware_build: str = "firmware_sim"


@dataclass(frozen=True)
class BatteryParams:
    """LiPo pack: ``cells`` in series, ``capacity_mah``, pack internal resistance (ohm) → sag under load."""

    cells: int = 3
    capacity_mah: float = 1000.0
    internal_resistance_ohm: float = 0.08
    initial_soc: float = 1.0
    ocv_curve: tuple[tuple[float, float], ...] = LIPO_OCV_CURVE


@dataclass(frozen=True)
class UbecParams:
    """The 5 V rail (buck converter) feeding the MCU, the ADK and the gimbal servos.

    Output is ``set_voltage_v`` while the battery stays ``dropout_v`` above it and the load stays under
    ``current_limit_a``; past the limit the output folds back (V = set · limit / load)."""

    set_voltage_v: float = 5.0
    current_limit_a: float = 3.0
    dropout_v: float = 0.5
    efficiency: float = 0.85
    electronics_current_a: float = 0.15  # MCU + ADK + USB host, drawn whenever the rail is up


@dataclass(frozen=True)
class PowerThresholds:
    """Staged thresholds on the (filtered) loaded battery voltage, volts per cell, and the brown-out
    detector on the UBEC rail. Each stage clears ``hysteresis_v_cell`` above where it was entered."""

    warn_v_cell: float = 3.50
    limit_v_cell: float = 3.40
    shed_v_cell: float = 3.30
    hysteresis_v_cell: float = 0.10
    limit_throttle: float = 0.5  # LIMIT caps each rotor at this fraction of its pulse range
    brownout_v: float = 4.30  # MCU brown-out detector level on the UBEC rail (ATmega BODLEVEL 4.3 V)
    brownout_release_v: float = 4.50  # the MCU leaves reset when the rail is back above this
    filter_time_constant_s: float = 0.05  # the battery ADC reading is low-pass filtered


@dataclass(frozen=True)
class MotorParams:
    """Rotor ESC + BLDC motor: first-order speed response towards the calibration map's steady speed,
    slower when coasting down (no active braking). Electrical power = drag power / efficiency + idle,
    drag power = rated_power_w · (ω/rated_speed)³, plus the power that accelerates the rotor (J ω ω̇)."""

    time_constant_s: float = 0.15
    coast_time_constant_s: float = 1.5
    inertia_kg_m2: float = 1.0e-5
    rated_speed_rad_s: float = 600.0
    rated_power_w: float = 12.0
    efficiency: float = 0.75
    idle_current_a: float = 0.05  # an ESC receiving pulses draws this at zero speed


@dataclass(frozen=True)
class GimbalParams:
    """Gimbal servo driver (powered from the UBEC rail): first-order response to its commanded rate
    (RATE mode) or angle (ANGLE mode, slew-limited to ``max_rate_rad_s``); current grows with rate."""

    time_constant_s: float = 0.05
    max_rate_rad_s: float = 2.0
    idle_current_a: float = 0.02
    current_per_rad_s_a: float = 0.15


@dataclass(frozen=True)
class PowerConfig:
    battery: BatteryParams = field(default_factory=BatteryParams)
    ubec: UbecParams = field(default_factory=UbecParams)
    thresholds: PowerThresholds = field(default_factory=PowerThresholds)
    update_period_s: float = 0.005  # how often the power manager samples and integrates


PULSE_GAP_US = 20
"""Low time (µs) every frame keeps after its pulse (``firmware/include/pulses.h``, ``PULSE_GAP_TICKS``): a
width that reaches the frame's end (2500 µs in a 490 Hz frame of 2041 µs) leaves the timer's compare value
at or past its TOP, and fast-PWM mode 14 then never clears the pin: a constant high, no pulse at all."""


def longest_pulse_fine(frame_rate_hz: float) -> int:
    """The longest fine width (1/512 µs) a frame at ``frame_rate_hz`` holds: the firmware's period in whole
    0.5 µs ticks (its timer's TOP + 1, ``pulses_init``) less :data:`PULSE_GAP_US`, so that even a frame the
    dither lengthens by a tick ends low. Above ~392 Hz it is shorter than ``PULSE_MAX_US``."""
    period_ticks = round(1e6 / TICK_US / frame_rate_hz)
    return (period_ticks - round(PULSE_GAP_US / TICK_US)) << FRACTION_BITS


MCU_WATCHDOG_MIN_S = 0.1
"""s: the shortest MCU watchdog a board takes (the firmware's ``config.c`` alike). The firmware's longest
main-loop pass — a calibration set reassembled, validated in float32 and stored, ~33 ms — must fit in it,
with room: at 15–30 ms three uploads in a row, host input alone, reset the board by its watchdog and left
a set it had acknowledged damaged in EEPROM (below 32 ms the loop itself restarts the 16 ms hardware
watchdog)."""


@dataclass(frozen=True)
class BoardConfig:
    """Everything that shapes one emulated board.

    Pulse channels are ordered gimbal 0, rotor 0, gimbal 1, rotor 1, … (as in ``RawPulses``).
    ``tick_s`` is the main-loop period: received bytes are handled on tick boundaries.

    ``esc_supply_switch``: the board has a switch that cuts the rotor ESCs' supply (the C firmware's
    ESC_SUPPLY_CUT pin), so the ESC endpoint procedure power-cycles the ESC itself; without one it asks
    the operator to connect the supply. ``unit_spread_seed``: None makes every unit ideal (its motor and
    servo are exactly its calibration maps); a seed draws each unit's true motor and servo around the
    stated models (``hil.calibration.generate.bench_units``), its ESC at ``esc``'s factory endpoints
    until programmed: a bench to calibrate.
    """

    n_units: int = 4
    frame_rate_hz: float = 50.0
    telemetry_rate_hz: float = 20.0
    heartbeat_rate_hz: float = 5.0
    link_timeout_s: float = 0.25
    mcu_watchdog_s: float = 0.5
    tick_s: float = 0.001
    boot_time_s: float = 0.05  # from reset release until the main loop runs (outputs off meanwhile)
    rotor_safe_us: int = 1000  # rotor ESC output when disarmed / failsafe / shed (minimum throttle)
    ppm: bool = False  # also generate a PPM-sum train of the first 8 channels
    timeline_frames: int = 4096  # pulse frames kept in the inspectable timeline
    rx_buffer_bytes: int = 4096  # UART receive ring; bytes beyond it are dropped and counted
    tx_buffer_bytes: int = 65536  # frames that do not fit are dropped and counted
    dead_esc_detect_s: float = 0.5  # commanded output without response for this long → DEAD_ESC
    esc_supply_switch: bool = False  # the board can cut the ESCs' supply (ESC endpoint programming)
    unit_spread_seed: int | None = None  # None: ideal units (= their calibration); else bench units
    identity: Identity = field(default_factory=Identity)
    power: PowerConfig = field(default_factory=PowerConfig)
    motor: MotorParams = field(default_factory=MotorParams)
    gimbal: GimbalParams = field(default_factory=GimbalParams)
    esc: EscParams = field(default_factory=EscParams)
    seed: int = 0  # seeds the fault injector's random numbers

    @property
    def n_channels(self) -> int:
        return 2 * self.n_units

    def replace(self, **changes: object) -> BoardConfig:
        """A copy with ``changes`` applied, validated."""
        cfg = dataclasses.replace(self, **changes)  # type: ignore[arg-type]
        cfg.validate()
        return cfg

    def validate(self) -> None:
        """Raise :class:`ConfigError` naming the first bad field."""
        w = "BoardConfig"
        _int_in(self.n_units, 1, MAX_UNITS, f"{w}.n_units")
        _num_in(self.frame_rate_hz, 50.0, 490.0, f"{w}.frame_rate_hz")
        _num_in(self.telemetry_rate_hz, 0.1, 1000.0, f"{w}.telemetry_rate_hz")
        _num_in(self.heartbeat_rate_hz, 0.1, 1000.0, f"{w}.heartbeat_rate_hz")
        _num_in(self.link_timeout_s, 0.01, 60.0, f"{w}.link_timeout_s")
        _num_in(self.mcu_watchdog_s, MCU_WATCHDOG_MIN_S, 8.0, f"{w}.mcu_watchdog_s")
        _num_in(self.tick_s, 1e-5, 0.01, f"{w}.tick_s")
        _num_in(self.boot_time_s, 0.0, 10.0, f"{w}.boot_time_s")
        _int_in(self.rotor_safe_us, PULSE_MIN_US, PULSE_MAX_US, f"{w}.rotor_safe_us")
        # The safe pulse goes out unclamped (the link watchdog's stop, from the firmware's tick interrupt):
        # one past the frame's end is a constant high on the pin, no pulse, an ESC left to its own failsafe.
        longest_us = longest_pulse_fine(self.frame_rate_hz) / FINE_PER_US
        if self.rotor_safe_us > longest_us:
            raise ConfigError(
                f"{self.rotor_safe_us} µs does not fit a {self.frame_rate_hz:g} Hz frame "
                f"(at most {longest_us:g} µs)",
                f"{w}.rotor_safe_us",
            )
        _int_in(self.timeline_frames, 1, 10_000_000, f"{w}.timeline_frames")
        _int_in(self.rx_buffer_bytes, 64, 1 << 24, f"{w}.rx_buffer_bytes")
        _int_in(self.tx_buffer_bytes, 512, 1 << 26, f"{w}.tx_buffer_bytes")
        _num_in(self.dead_esc_detect_s, 0.01, 60.0, f"{w}.dead_esc_detect_s")
        b = self.power.battery
        # two cells at least: one (4.2 V full) cannot hold the UBEC's rail above the MCU's brown-out
        # release, and the board never boots (a scenario's cells = 1 was a handshake timeout)
        _int_in(b.cells, 2, 12, f"{w}.power.battery.cells")
        _num_in(b.capacity_mah, 1.0, 1e6, f"{w}.power.battery.capacity_mah")
        _num_in(b.internal_resistance_ohm, 0.0, 10.0, f"{w}.power.battery.internal_resistance_ohm")
        _num_in(b.initial_soc, 0.0, 1.0, f"{w}.power.battery.initial_soc")
        curve = b.ocv_curve
        if len(curve) < 2 or any(
            not (s1 < s2 and v1 <= v2) for (s1, v1), (s2, v2) in zip(curve, curve[1:], strict=False)
        ):
            raise ConfigError(
                "must be increasing in SoC and non-decreasing in voltage", f"{w}.power.battery.ocv_curve"
            )
        if curve[0][0] > 0.0 or curve[-1][0] < 1.0:
            raise ConfigError("must cover SoC 0..1", f"{w}.power.battery.ocv_curve")
        u = self.power.ubec
        _num_in(u.set_voltage_v, 1.0, 24.0, f"{w}.power.ubec.set_voltage_v")
        _num_in(u.current_limit_a, 0.01, 100.0, f"{w}.power.ubec.current_limit_a")
        _num_in(u.dropout_v, 0.0, 5.0, f"{w}.power.ubec.dropout_v")
        _num_in(u.efficiency, 0.1, 1.0, f"{w}.power.ubec.efficiency")
        _num_in(u.electronics_current_a, 0.0, 10.0, f"{w}.power.ubec.electronics_current_a")
        t = self.power.thresholds
        where = f"{w}.power.thresholds"
        full_cell_v = curve[-1][1]
        for name in ("warn_v_cell", "limit_v_cell", "shed_v_cell"):
            _num_in(getattr(t, name), 0.0, full_cell_v, f"{where}.{name}")
        if not (t.warn_v_cell > t.limit_v_cell > t.shed_v_cell > 0):
            raise ConfigError(
                f"need warn_v_cell > limit_v_cell > shed_v_cell > 0 (got {t.warn_v_cell}, {t.limit_v_cell}, "
                f"{t.shed_v_cell})",
                where,
            )
        _num_in(t.hysteresis_v_cell, 0.0, 1.0, f"{where}.hysteresis_v_cell")
        # A stage is left only hysteresis above its level: at or above a full cell (the OCV curve's top)
        # one entered never clears, and thresholds above it shed the load of a full pack from power-on.
        if not t.warn_v_cell + t.hysteresis_v_cell < full_cell_v:
            raise ConfigError(
                f"warn_v_cell + hysteresis_v_cell = {t.warn_v_cell + t.hysteresis_v_cell:g} V must lie below "
                f"a full cell ({full_cell_v:g} V): the stage would never clear",
                f"{where}.warn_v_cell",
            )
        _num_in(t.limit_throttle, 0.0, 1.0, f"{where}.limit_throttle")
        if not (0 < t.brownout_v <= t.brownout_release_v < u.set_voltage_v + 1e-9):
            raise ConfigError(
                f"need 0 < brownout_v <= brownout_release_v <= ubec set voltage (got {t.brownout_v}, "
                f"{t.brownout_release_v}, {u.set_voltage_v})",
                where,
            )
        # The rail is at most the pack less the UBEC's dropout (the set voltage is held above): a release
        # level at or above what a full pack puts on it holds the MCU in reset for good (a handshake
        # timeout, not an error).
        full_pack_rail_v = b.cells * full_cell_v - u.dropout_v
        if not t.brownout_release_v < full_pack_rail_v:
            raise ConfigError(
                f"{t.brownout_release_v:g} V is not below the {full_pack_rail_v:g} V a full {b.cells}-cell "
                f"pack puts on the UBEC rail (less its {u.dropout_v:g} V dropout): the MCU would never leave "
                "reset",
                f"{where}.brownout_release_v",
            )
        _num_in(t.filter_time_constant_s, 0.0, 10.0, f"{where}.filter_time_constant_s")
        _num_in(self.power.update_period_s, 1e-4, 0.1, f"{w}.power.update_period_s")
        m = self.motor
        _num_in(m.time_constant_s, 1e-3, 100.0, f"{w}.motor.time_constant_s")
        _num_in(m.coast_time_constant_s, 1e-3, 1000.0, f"{w}.motor.coast_time_constant_s")
        _num_in(m.inertia_kg_m2, 0.0, 1.0, f"{w}.motor.inertia_kg_m2")
        _num_in(m.rated_speed_rad_s, 1.0, 1e5, f"{w}.motor.rated_speed_rad_s")
        _num_in(m.rated_power_w, 0.0, 1e4, f"{w}.motor.rated_power_w")
        _num_in(m.efficiency, 0.05, 1.0, f"{w}.motor.efficiency")
        _num_in(m.idle_current_a, 0.0, 10.0, f"{w}.motor.idle_current_a")
        g = self.gimbal
        _num_in(g.time_constant_s, 1e-4, 100.0, f"{w}.gimbal.time_constant_s")
        _num_in(g.max_rate_rad_s, 0.01, 20.0, f"{w}.gimbal.max_rate_rad_s")
        _num_in(g.idle_current_a, 0.0, 10.0, f"{w}.gimbal.idle_current_a")
        _num_in(g.current_per_rad_s_a, 0.0, 10.0, f"{w}.gimbal.current_per_rad_s_a")
        if self.unit_spread_seed is not None:
            _int_in(self.unit_spread_seed, 0, 2**63 - 1, f"{w}.unit_spread_seed")
        e = self.esc
        _num_in(e.factory_low_us, PULSE_MIN_US, PULSE_MAX_US, f"{w}.esc.factory_low_us")
        _num_in(e.factory_high_us, e.factory_low_us + e.min_span_us, PULSE_MAX_US, f"{w}.esc.factory_high_us")
        _num_in(e.arm_fraction, 0.0, 0.5, f"{w}.esc.arm_fraction")
        _num_in(e.program_fraction, 0.5, 1.0, f"{w}.esc.program_fraction")
        _num_in(e.high_ack_s, 0.01, 60.0, f"{w}.esc.high_ack_s")
        _num_in(e.low_ack_s, 0.01, 60.0, f"{w}.esc.low_ack_s")
        _num_in(e.stable_us, 0.0, 100.0, f"{w}.esc.stable_us")
        _num_in(e.min_span_us, 100.0, 1500.0, f"{w}.esc.min_span_us")
        for name, limit in _IDENTITY_LIMITS.items():
            n = len(getattr(self.identity, name).encode("utf-8"))
            if n > limit:
                raise ConfigError(f"{n} bytes > {limit} (its HelloReply field)", f"{w}.identity.{name}")


_IDENTITY_LIMITS = {
    "manufacturer": 24,
    "model": 24,
    "description": 48,
    "version": 16,
    "uri": 64,
    "serial": 24,
    "firmware_build": 24,
}


def _num_in(value: float, lo: float, hi: float, where: str) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(f"{value!r} is not a finite number", where)
    if not lo <= value <= hi:
        raise ConfigError(f"{value!r} is outside {lo:g}..{hi:g}", where)


def _int_in(value: int, lo: int, hi: int, where: str) -> None:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ConfigError(f"{value!r} is not an integer", where)
    if not lo <= value <= hi:
        raise ConfigError(f"{value!r} is outside {lo}..{hi}", where)
