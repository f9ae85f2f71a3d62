"""Whatever the image builder (``eeprom.config_block``) writes, the firmware takes (its parser's status 0);
whatever the firmware refuses, the builder refuses with a :class:`ConfigError` naming the field — every
field of the configuration block, the firmware's own parser (firmware/src/config.c through the host
library) against ``BoardConfig.validate`` and ``eeprom.check_hardware``.

The builder checked in double what the firmware checks in float32, on the float32 the block holds, and
checked some fields against the emulator's limits rather than the firmware's. So it wrote blocks the
firmware refused, falling back to its defaults with nothing but a boot Log to say so:

* ``power.update_period_s`` under 1 ms (the emulator takes 0.1 ms; the firmware counts its power manager in
  whole milliseconds) — and a period of 1.5 ms, which the firmware took and ran every 2 ms while filtering
  the battery reading as if every 1.5 ms;
* a threshold too small for float32 (``shed_v_cell = 1e-300``: stored as 0, not above 0);
* two thresholds a hair apart (``warn_v_cell`` 1e-12 V above ``limit_v_cell``: stored equal);
* ``warn_v_cell + hysteresis_v_cell`` a hair under a full cell in double, on it in float32;
* an ``ocv_curve`` other than the one compiled into the firmware: the block has no room for it, so the
  firmware ran on its own curve, and a warn level above its full cell.
"""

from __future__ import annotations

import dataclasses
import struct

import hypothesis.strategies as st
import pytest
from hypothesis import HealthCheck, example, given, settings

from firmware_sim.avr import eeprom
from firmware_sim.avr.hostlib import config_parse
from firmware_sim.board.config import LIPO_OCV_CURVE, BoardConfig
from protocol.calibration.checks import f32
from protocol.crc import crc16_ccitt_false
from protocol.errors import ConfigError

PROBLEMS = (  # config.c's problem names, by index
    "none",
    "magic, version or CRC",
    "n_units",
    "frame_rate_hz",
    "telemetry_rate_hz",
    "heartbeat_rate_hz",
    "link_timeout_s",
    "mcu_watchdog_s",
    "rotor_safe_us",
    "ppm",
    "cells",
    "battery_resistance_ohm",
    "warn/limit/shed_v_cell",
    "hysteresis_v_cell",
    "limit_throttle",
    "brownout_release_v",
    "filter_time_constant_s",
    "power_update_period_s",
    "ubec_current_limit_a",
    "esc_supply_switch",
    "baud",
    "link",
)
SOURCES = {name: source for name, _, source in eeprom.CONFIG_FIELDS}
BASE = BoardConfig()
LIHV_CURVE = (*LIPO_OCV_CURVE[:-1], (1.0, 4.35))  # a high-voltage LiPo: 4.35 V full


def where_the_builder_names(problem: str) -> str:
    """The ``ConfigError.where`` prefix the builder must name for the firmware's ``problem``."""
    if problem == "warn/limit/shed_v_cell":
        return "BoardConfig.power.thresholds"
    source = SOURCES["power_update_period_s" if problem == "power_update_period_s" else problem]
    return "BoardConfig." + source


def configured(d: dict[str, object]) -> BoardConfig:
    """The default BoardConfig with the drawn fields (unvalidated: the builder validates)."""
    p = BASE.power

    def pick(*names: str) -> dict[str, object]:
        return {k: v for k, v in d.items() if k in names}

    power = dataclasses.replace(
        p,
        battery=dataclasses.replace(p.battery, **pick("cells", "internal_resistance_ohm", "ocv_curve")),
        thresholds=dataclasses.replace(
            p.thresholds,
            **pick(
                "warn_v_cell",
                "limit_v_cell",
                "shed_v_cell",
                "hysteresis_v_cell",
                "limit_throttle",
                "brownout_release_v",
                "filter_time_constant_s",
            ),
        ),
        ubec=dataclasses.replace(p.ubec, **pick("current_limit_a", "set_voltage_v")),
        **pick("update_period_s"),
    )
    top = pick(
        "n_units",
        "frame_rate_hz",
        "telemetry_rate_hz",
        "heartbeat_rate_hz",
        "link_timeout_s",
        "mcu_watchdog_s",
        "rotor_safe_us",
        "ppm",
        "esc_supply_switch",
    )
    return dataclasses.replace(BASE, power=power, **top)


def raw_block(cfg: BoardConfig) -> bytes:
    """``cfg``'s block as another tool would write it: packed field by field, nothing checked."""
    values = []
    for _, code, source in eeprom.CONFIG_FIELDS:
        v = eeprom._value(cfg, source, eeprom.DEFAULT_BAUD, eeprom.DEFAULT_LINK)
        if code.endswith("s"):
            v = str(v).encode("ascii").ljust(eeprom.SERIAL_LEN, b"\0")
        elif code == "f":
            v = float(v)
        else:
            v = int(v)
        values.append(v)
    body = eeprom.CONFIG_STRUCT.pack(*values, 0)[:-2]
    return body + struct.pack("<H", crc16_ccitt_false(body))


def near(x: float, edges: list[float]) -> st.SearchStrategy[float]:
    """Around ``x`` (±30 %), and the drawn edges exactly."""
    return st.one_of(st.floats(x * 0.7, x * 1.3), st.sampled_from(edges))


def hair_below(x: float) -> st.SearchStrategy[float]:
    """Just under ``x``: what rounds onto it in float32."""
    return st.sampled_from([1e-15, 1e-12, 1e-9, 3e-8, 1e-7, 1e-6]).map(lambda eps: x - eps)


FIELD_VALUES: dict[str, st.SearchStrategy[object]] = {
    "n_units": st.integers(0, 8),
    "frame_rate_hz": st.one_of(st.floats(49.0, 491.0), st.sampled_from([50.0, 392.0, 490.0, 333.3333333])),
    "telemetry_rate_hz": st.one_of(st.floats(0.05, 1100.0), st.sampled_from([0.1, 1000.0])),
    "heartbeat_rate_hz": st.one_of(st.floats(0.05, 1100.0), st.sampled_from([0.1, 1000.0])),
    "link_timeout_s": st.one_of(st.floats(0.005, 61.0), st.sampled_from([0.01, 60.0])),
    "mcu_watchdog_s": st.one_of(st.floats(0.05, 9.0), st.sampled_from([0.1, 8.0])),
    "rotor_safe_us": st.integers(700, 2600),
    "ppm": st.booleans(),
    "cells": st.integers(1, 6),
    "internal_resistance_ohm": st.one_of(st.floats(0.0, 11.0), st.sampled_from([-0.0, 10.0])),
    "warn_v_cell": st.one_of(near(3.5, [3.5, 4.1, 4.2]), hair_below(4.2 - 0.1)),
    "limit_v_cell": st.one_of(near(3.4, [3.4]), hair_below(3.5)),
    "shed_v_cell": st.one_of(near(3.3, [3.3]), st.sampled_from([1e-300, 1e-46, 5e-324, 1e-38])),
    "hysteresis_v_cell": st.one_of(st.floats(0.0, 1.1), hair_below(0.1), st.sampled_from([0.1, 0.7])),
    "limit_throttle": st.one_of(st.floats(0.0, 1.0), st.sampled_from([0.0, 1.0, -0.0])),
    "brownout_release_v": st.one_of(st.floats(4.3, 6.5), st.sampled_from([4.5, 6.392])),
    "set_voltage_v": st.sampled_from([5.0, 8.0]),
    "filter_time_constant_s": st.one_of(st.floats(0.0, 11.0), st.sampled_from([0.0, 10.0])),
    "update_period_s": st.one_of(
        st.floats(1e-5, 0.11),
        st.integers(1, 100).map(lambda ms: ms / 1000),
        st.sampled_from([1e-4, 5e-4, 0.0015, 1e-3, 0.005, 0.1]),
    ),
    "current_limit_a": st.one_of(st.floats(0.005, 101.0), st.sampled_from([0.01, 100.0])),
    "esc_supply_switch": st.booleans(),
    "ocv_curve": st.sampled_from([LIPO_OCV_CURVE, LIHV_CURVE, ((0.0, 3.0), (1.0, 4.2))]),
}
fields = st.fixed_dictionaries({}, optional=FIELD_VALUES)
one_field = st.sampled_from(sorted(set(FIELD_VALUES) - {"ocv_curve"})).flatmap(
    lambda name: FIELD_VALUES[name].map(lambda value: {name: value})
)


def built_or_refused(cfg: BoardConfig) -> tuple[bytes | None, ConfigError | None]:
    try:
        return eeprom.config_block(cfg), None
    except ConfigError as refused:
        return None, refused


@pytest.mark.firmware
@settings(max_examples=1500, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(d=fields)
@example(d={"update_period_s": 1e-4})  # the emulator's floor, under the firmware's millisecond
@example(d={"update_period_s": 0.0015})  # kept by the firmware every 2 ms, filtered as every 1.5
@example(d={"shed_v_cell": 1e-300})  # stored as 0
@example(d={"limit_v_cell": 3.5 - 1e-12})  # stored equal to warn_v_cell
@example(d={"warn_v_cell": 3.671359492945383, "hysteresis_v_cell": 0.5286404070546172})  # sum rounds up
@example(d={"ocv_curve": LIHV_CURVE, "warn_v_cell": 4.1, "hysteresis_v_cell": 0.15})  # not the firmware's
def test_what_the_builder_writes_the_firmware_takes(d):
    cfg = configured(d)
    block, _ = built_or_refused(cfg)
    if block is None:
        return
    status, got, problem = config_parse(block)
    assert status == 0, f"{d}: the builder wrote it, the firmware refused it ({PROBLEMS[problem]})"
    assert got["n_units"] == cfg.n_units and got["cells"] == cfg.power.battery.cells
    assert got["shed_v_cell"] == f32(cfg.power.thresholds.shed_v_cell)


@pytest.mark.firmware
@settings(max_examples=800, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(d=one_field)
@example(d={"update_period_s": 1e-4})
@example(d={"shed_v_cell": 1e-300})
@example(d={"limit_v_cell": 3.5 - 1e-12})
def test_what_the_firmware_refuses_the_builder_refuses_naming_the_field(d):
    """One field changed at a time (two bad fields may be named in another order): a block with it,
    written by another tool, that the firmware refuses, the builder refuses, naming that field."""
    cfg = configured(d)
    try:
        status, _, problem = config_parse(raw_block(cfg))
    except struct.error:
        return  # not even packable (a unit count past a byte)
    if status == 0:
        return
    _, refused = built_or_refused(cfg)
    assert refused is not None, f"{d}: the firmware refused {PROBLEMS[problem]}, the builder wrote it"
    named = where_the_builder_names(PROBLEMS[problem])
    assert refused.where.startswith(named) or named.startswith(refused.where), (
        f"{d}: the firmware refused {PROBLEMS[problem]}, the builder named {refused.where} ({refused})"
    )


@pytest.mark.firmware
@pytest.mark.parametrize("period_s", [0.001, 0.002, 0.005, 0.02, 0.1])
def test_a_whole_millisecond_power_period_is_written_and_taken(period_s):
    """The other side of the millisecond rule: every whole-millisecond period in range goes through."""
    cfg = BASE.replace(power=dataclasses.replace(BASE.power, update_period_s=period_s))
    status, _, problem = config_parse(eeprom.config_block(cfg))
    assert status == 0, PROBLEMS[problem]


@pytest.mark.firmware
@pytest.mark.parametrize("period_s", [0.0015, 0.0101, 0.05005])
def test_the_firmware_refuses_a_power_period_it_cannot_keep(period_s):
    """A block (written by another tool) asking for a period between milliseconds: the firmware's
    power manager runs on its millisecond clock, so it refuses the block and names the field."""
    cfg = dataclasses.replace(BASE, power=dataclasses.replace(BASE.power, update_period_s=period_s))
    status, _, problem = config_parse(raw_block(cfg))
    assert status == 3 and PROBLEMS[problem] == "power_update_period_s", (status, PROBLEMS[problem])
    with pytest.raises(ConfigError) as refused:
        eeprom.config_block(cfg)
    assert refused.value.where == "BoardConfig.power.update_period_s"


@pytest.mark.firmware
@settings(max_examples=300, deadline=None)
@given(serial=st.text(st.characters(max_codepoint=0x7F), max_size=24))
@example(serial="LAB\x0007")  # announced as "LAB"
def test_a_serial_the_builder_writes_is_the_serial_the_firmware_announces(serial):
    """The firmware reads the block's serial up to its first NUL: the builder wrote one with a NUL inside,
    and the board announced (and derived its boot ids from) only what stood before it."""
    cfg = dataclasses.replace(BASE, identity=dataclasses.replace(BASE.identity, serial=serial))
    block, refused = built_or_refused(cfg)
    if block is None:
        assert refused is not None and refused.where == "BoardConfig.identity.serial"
        return
    status, got, problem = config_parse(block)
    assert status == 0, PROBLEMS[problem]
    assert got["serial"] == serial, f"configured {serial!r}, the firmware announces {got['serial']!r}"
