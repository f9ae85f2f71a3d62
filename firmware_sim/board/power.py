"""The board's power handling: the battery and UBEC rail solved against the loads (hardware, always
running), and the firmware's power manager around them — the staged thresholds (WARN → LIMIT → SHED,
BROWN_OUT while the rail is in the MCU's brown-out zone), the SHED latch (rotors stay stopped until a
new ``Arm``), the UBEC over-current report and the brown-out detector's trip and release levels.

The models themselves (``Battery``, ``ubec_output``, ``PowerManager``) are in :mod:`.power_models`.
"""

from __future__ import annotations

from collections.abc import Sequence

from protocol.messages import PowerState, Severity

from .actuators import UnitModel, esc_power_w
from .codes import LogCode
from .config import PowerConfig, UbecParams
from .faults import FaultInjector
from .power_models import Battery, PowerManager, PowerReading, ubec_input_power, ubec_output
from .telemetry import Outbox

_SHED = PowerState.SHED  # looked up once: an enum member's lookup costs about 60 ns, asked at 200 Hz


def solve_supply(
    reading: PowerReading,
    battery: Battery,
    ubec: UbecParams,
    units: Sequence[UnitModel],
    faults: FaultInjector,
    now: float,
) -> None:
    """Battery terminal voltage and current, UBEC rail voltage and current for the units' present loads
    at ``now`` (s, battery sag faults applied), written into ``reading``."""
    if faults.sags or battery.sag_v or battery.extra_resistance_ohm:
        battery.sag_v, battery.extra_resistance_ohm = faults.battery_sag(now)
    # The loads are solved as constant power at the last voltage (their weak voltage dependence lags
    # one physics step, a few ms).
    v = reading.battery_v if reading.battery_v > 0 else battery.ocv()
    gimbal_a, rotor_w = unit_loads(units, v)
    rail_load = ubec.electronics_current_a + gimbal_a
    rail_v, rail_a, over = ubec_output(ubec, v, rail_load)
    p = rotor_w + ubec_input_power(ubec, rail_v, rail_a)
    v, amps = battery.terminal(p)
    rail_v, rail_a, over = ubec_output(ubec, v, rail_load)
    reading.battery_v, reading.battery_a, reading.soc = v, amps, battery.soc
    reading.ubec_v, reading.ubec_a, reading.ubec_overcurrent = rail_v, rail_a, over


def unit_loads(units: Sequence[UnitModel], battery_v: float) -> tuple[float, float]:
    """The units' servo current from the UBEC rail (A) and the ESCs' power from the battery (W) at
    ``battery_v`` (V): the sums, in unit order, of :meth:`UnitModel.gimbal_current_a` and
    :meth:`UnitModel.rotor_power_w` (the references), in one loop — it runs at every physics step,
    ~20 000 times a default run, where two method calls per unit were a third of the supply's cost; the
    ESC's draw is the one formula both use (:func:`~firmware_sim.board.actuators.esc_power_w`).
    An undriven unit adds nothing (the references' 0.0: the sums are the same floats)."""
    gimbal_a = rotor_w = 0.0
    for u in units:
        if u.gimbal_driven:
            g = u.gimbal
            gimbal_a += g.idle_current_a + g.current_per_rad_s_a * abs(u.gimbal_rate)
        if u.rotor_driven:
            rotor_w += esc_power_w(u.motor, u.rotor_speed, u.rotor_accel, battery_v)
    return gimbal_a, rotor_w


class PowerSupervisor:
    """The firmware's power manager: ``state`` is the stage telemetry reports; stage changes and UBEC
    over-current are logged to the host through ``outbox``."""

    def __init__(self, config: PowerConfig, outbox: Outbox) -> None:
        self.config = config
        self.manager = PowerManager(config.thresholds, config.battery.cells)
        self.state = PowerState.NORMAL
        self.shed_latched = False
        self.ubec_over = False  # the last sample's over-current (kept across resets: reported on change)
        self._out = outbox

    def reset(self) -> None:
        """MCU reset: the filter, the stage and the SHED latch start over."""
        self.manager.reset()
        self.state = PowerState.NORMAL
        self.shed_latched = False

    @property
    def power_ok(self) -> bool:
        """Whether an ``Arm`` may be accepted (not while shedding load or browning out)."""
        return self.state < _SHED

    @property
    def shedding(self) -> bool:
        """Rotors held at the safe width: the SHED stage now, or latched since it was reached armed."""
        return self.shed_latched or self.state >= _SHED

    def browned_out(self, reading: PowerReading) -> bool:
        """The MCU's brown-out detector trips (a reset) at this rail voltage."""
        return self.manager.browned_out(reading.ubec_v)

    def released(self, reading: PowerReading) -> bool:
        """The rail is high enough for the MCU to leave reset."""
        return self.manager.released(reading.ubec_v)

    def update(self, reading: PowerReading, dt: float, motors_on: bool) -> None:
        """One sample of the power manager, ``dt`` s after the last (0 at boot); ``motors_on``: ARMED
        (reaching SHED, or BROWN_OUT straight from above it, then latches until the next ``Arm``)."""
        old = self.state
        new = self.manager.update(reading.battery_v, dt)
        if reading.ubec_v < self.config.thresholds.brownout_release_v:
            new = PowerState.BROWN_OUT  # the rail is in the MCU's brown-out zone: reset imminent
        self.state = new
        if new >= _SHED and not self.shed_latched and motors_on:  # a dip straight to BROWN_OUT latches too
            self.shed_latched = True
        if new is not old:
            sev = (
                Severity.INFO
                if new < old
                else (Severity.ERROR if new >= PowerState.SHED else Severity.WARNING)
            )
            self._out.log(
                sev,
                LogCode.POWER,
                f"power {old.name} -> {new.name} (battery {reading.battery_v:.2f} V, "
                f"{self.manager.filtered_v_cell or 0:.3f} V/cell, rail {reading.ubec_v:.2f} V)",
            )
        over = reading.ubec_overcurrent
        if over and not self.ubec_over:
            self._out.log(
                Severity.WARNING,
                LogCode.UBEC_OVERCURRENT,
                f"UBEC over current: {reading.ubec_a:.2f} A > {self.config.ubec.current_limit_a:.2f} A",
            )
        self.ubec_over = over
