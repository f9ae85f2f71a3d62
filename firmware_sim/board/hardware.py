"""The board's hardware over one physics step in one function: the units' ESCs and motors, the battery's
coulomb count and the supply (battery terminals and UBEC rail) solved against the units' loads.

:func:`step_hardware` is the fused form of what the board's physics step did as separate calls — each
unit's :meth:`~.actuators.UnitModel.step`, :meth:`~.power_models.Battery.discharge` and
:func:`~.power.solve_supply` (with :func:`~.power.unit_loads`, ``ubec_input_power`` and ``Battery.terminal``
inside it) — which stay as the references it is tested against
(``tests/test_board_hardware.py``: the same floats, bit for bit, on the same objects).

Why: the board runs it ~20 000 times a default closed-loop run (every board event and every world step
that moves board time), and its ~20 Python calls each time were the largest single part of the world's
own Python (docs/compiled.md, "The world's half"). A unit the world drives (``UnitModel.follow``) does not
move here, so its step is its ESC's supply and arming and two flags; its loads are summed in the same loop.
The arithmetic is the references' own, operation for operation and in the same order (the ESC's draw,
:func:`~.actuators.esc_power_w`, and the UBEC's output, :func:`~.power_models.ubec_output`, spelt out
here too: a call each was a fifth of the step): the results are the same floats, not merely close ones.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from .actuators import UnitModel
from .config import UbecParams
from .esc import _ARMED, _OFF
from .faults import FaultInjector
from .power import unit_loads
from .power_models import Battery, PowerReading


def step_hardware(
    unit_channels: Sequence[tuple[UnitModel, int, int]],
    outputs: Sequence[float | None],
    now: float,
    dt: float,
    supply_on: bool,
    reading: PowerReading,
    battery: Battery,
    ubec: UbecParams,
    faults: FaultInjector,
) -> None:
    """The hardware at ``now`` (s), ``dt`` > 0 s after its last step, with the pulses ``outputs`` (µs per
    channel, None: no pulse) on the pins and the board's ESC supply switch ``supply_on``: every unit
    ``(model, gimbal channel, rotor channel)`` steps as :meth:`UnitModel.step` at the last battery voltage,
    the battery discharges at the last current as :meth:`Battery.discharge`, and ``reading`` gets the
    supply :func:`~.power.solve_supply` solves for the units' loads. Dead channels are the caller's to
    mark first (``unit.rotor_dead``, ``unit.gimbal_dead``)."""
    v = reading.battery_v
    loads_known = v > 0  # the loads are solved at the last voltage: known before the battery moves
    gimbal_a = rotor_w = 0.0
    for unit, g_ch, r_ch in unit_channels:
        g_us, r_us = outputs[g_ch], outputs[r_ch]
        if unit._external_t is None:  # the unit's own motor model moves it
            unit.step(now, dt, g_us, r_us, supply_on, v)
        else:  # UnitModel.step of a followed unit: its ESC and two flags (dt > 0 here)
            esc = unit.esc
            rotor_dead = unit.rotor_dead
            powered = supply_on and unit.esc_connected
            if not (powered and esc.mode is _ARMED):  # EmulatedEsc.update returns at once on that
                esc.update(now, None if rotor_dead else r_us, powered)
            unit.rotor_driven = r_us is not None and not rotor_dead and esc.mode is not _OFF
            unit.gimbal_driven = g_us is not None and not unit.gimbal_dead
        if loads_known:  # power.unit_loads, unit by unit in unit order
            if unit.gimbal_driven:
                g = unit.gimbal
                gimbal_a += g.idle_current_a + g.current_per_rad_s_a * abs(unit.gimbal_rate)
            if unit.rotor_driven:  # actuators.esc_power_w, spelt out
                m = unit.motor
                speed = unit.rotor_speed
                w = abs(speed)
                drag = m.rated_power_w * (w / m.rated_speed_rad_s) ** 3
                accel = m.inertia_kg_m2 * w * unit.rotor_accel
                if speed < 0.0:
                    accel = -accel
                if accel < 0.0:
                    accel = 0.0
                rotor_w += (drag + accel) / m.efficiency + m.idle_current_a * v
    # Battery.discharge
    soc = battery.soc - reading.battery_a * dt / (battery.params.capacity_mah * 3.6)
    battery.soc = 0.0 if soc < 0.0 else soc
    # power.solve_supply
    if faults.sags or battery.sag_v or battery.extra_resistance_ohm:
        battery.sag_v, battery.extra_resistance_ohm = faults.battery_sag(now)
    if not loads_known:
        v = battery.ocv()
        gimbal_a, rotor_w = unit_loads([unit for unit, _, _ in unit_channels], v)
    rail_load = ubec.electronics_current_a + gimbal_a
    set_v, limit_a, dropout_v = ubec.set_voltage_v, ubec.current_limit_a, ubec.dropout_v
    rail_v, rail_a, _ = _rail(set_v, limit_a, dropout_v, v, rail_load)
    p = rotor_w + rail_v * rail_a / ubec.efficiency  # ubec_input_power
    # Battery.terminal(p)
    voc = battery.ocv()
    if p <= 0.0 or voc <= 0.0:
        v, amps = voc, 0.0
    else:
        resistance = battery.params.internal_resistance_ohm + battery.extra_resistance_ohm
        disc = voc * voc - 4.0 * resistance * p
        v = voc / 2.0 if disc <= 0.0 else (voc + math.sqrt(disc)) / 2.0
        amps = p / v if v > 0 else 0.0
    rail_v, rail_a, over = _rail(set_v, limit_a, dropout_v, v, rail_load)
    reading.battery_v, reading.battery_a, reading.soc = v, amps, battery.soc
    reading.ubec_v, reading.ubec_a, reading.ubec_overcurrent = rail_v, rail_a, over


def _rail(
    set_v: float, limit_a: float, dropout_v: float, battery_v: float, load_a: float
) -> tuple[float, float, bool]:
    """:func:`~.power_models.ubec_output` on the UBEC's three figures, read once per step rather than
    twice: (rail volts, rail amps, over current) feeding ``load_a`` A from ``battery_v`` V."""
    v = set_v
    over = load_a > limit_a
    if over:
        v *= limit_a / load_a
    ceiling = battery_v - dropout_v
    if ceiling < v:
        v = ceiling
    if 0.0 > v:
        v = 0.0
    amps = load_a * v / set_v if set_v > 0 else 0.0
    return v, amps, over
