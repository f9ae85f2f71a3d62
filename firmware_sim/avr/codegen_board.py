"""Generate ``firmware/include/board_gen.h`` from ``firmware_sim.board.config`` and
``firmware_sim.avr.eeprom``: the EEPROM layout (configuration block offsets, calibration slots), the defaults
of ``BoardConfig`` the firmware falls back on, the identity strings, and the LiPo discharge curve.
:mod:`.codegen` writes and checks it with the protocol files.
"""

from __future__ import annotations

import dataclasses

from .c_literals import BANNER, bytes_init, c_float, f32

BOARD_SERIAL = "ADK0001"
"""The serial number a board reports until its EEPROM configuration gives it one."""


def generate_board() -> str:
    """The text of board_gen.h: EEPROM layout, BoardConfig defaults, identity, LiPo curve."""
    from firmware_sim.board import esc_calibration
    from firmware_sim.board.config import BoardConfig

    from . import eeprom

    cfg = BoardConfig()
    ident = cfg.identity
    h = [
        BANNER.replace("protocol/messages.py", "firmware_sim/board/config.py and firmware_sim/avr/eeprom.py"),
        "#ifndef BOARD_GEN_H",
        "#define BOARD_GEN_H",
        "",
        "/* EEPROM: the configuration block at 0, the boot counter, then one calibration slot per unit. */",
        f"#define EEPROM_CONFIG_MAGIC {eeprom.CONFIG_MAGIC:#06x}u",
        f"#define EEPROM_CONFIG_VERSION {eeprom.CONFIG_VERSION}u",
        f"#define EEPROM_CONFIG_SIZE {eeprom.CONFIG_SIZE}u",
        f"#define EEPROM_BOOT_COUNT_BASE {eeprom.BOOT_COUNT_BASE}u",
        f"#define EEPROM_BOOT_COUNT_SLOTS {eeprom.BOOT_COUNT_SLOTS}u",
        f"#define EEPROM_CAL_BASE {eeprom.CAL_BASE}u",
        f"#define EEPROM_SIZE {eeprom.EEPROM_SIZE}u",
        f"#define MAX_HW_UNITS {eeprom.MAX_HW_UNITS}u",
        f"#define SERIAL_LEN {eeprom.SERIAL_LEN}u",
        "",
        "/* The configuration's link byte (firmware_sim/avr/eeprom.py LINKS). */",
        *(f"#define LINK_{name.upper()} {i}u" for i, name in enumerate(eeprom.LINKS)),
        f"#define LINK_COUNT {len(eeprom.LINKS)}u",
        "",
        "/* UART0's clock, and how far from the rate asked for the rate it makes may lie (eeprom.py) */",
        f"#define UART_CLOCK_HZ {eeprom.UART_CLOCK_HZ}UL",
        f"#define UART_MAX_BAUD_ERROR_PERMILLE {eeprom.MAX_BAUD_ERROR_PERMILLE}UL",
        "",
    ]
    h += [f"#define CFG_OFF_{name.upper()} {off}u" for name, off in eeprom.field_offsets().items()]
    defaults = {
        "MOTOR_TIME_CONSTANT_S": c_float(f32(cfg.motor.time_constant_s)),
        "MOTOR_COAST_TIME_CONSTANT_S": c_float(cfg.motor.coast_time_constant_s),
        "GIMBAL_TIME_CONSTANT_S": c_float(f32(cfg.gimbal.time_constant_s)),
        "GIMBAL_MAX_RATE_RAD_S": c_float(cfg.gimbal.max_rate_rad_s),
    }
    board = dataclasses.replace(cfg, identity=dataclasses.replace(ident, serial=BOARD_SERIAL))
    block = eeprom.config_block(board)
    h += [
        "",
        "/* BoardConfig() defaults as a configuration block: what the firmware runs on without one */",
        "#define DEFAULT_CONFIG_BLOCK \\",
        "    { \\",
    ]
    h += [line + " \\" for line in bytes_init(block).splitlines()]
    h += ["    }", "", "/* BoardConfig() actuator time constants, for the units' estimated states */"]
    h += [f"#define CFG_DEFAULT_{k} {v}" for k, v in defaults.items()]
    h += [
        "",
        "/* The ESC endpoint procedure's rules (firmware_sim/board/esc_calibration.py) */",
        f"#define ESC_MIN_SPAN_US {esc_calibration.ESC_MIN_SPAN_US}u",
        f"#define ESC_MIN_SUPPLY_OFF_MS {esc_calibration.ESC_MIN_SUPPLY_OFF_MS}u",
        f"#define ESC_SUPPLY_WAIT_MS {esc_calibration.SUPPLY_WAIT_MS}UL",
    ]
    h += ["", "/* Identity (AOA accessory strings, firmware_sim.board.config.Identity) of the real board. */"]
    for name, value in (
        ("MANUFACTURER", ident.manufacturer),
        ("MODEL", ident.model),
        ("DESCRIPTION", "VSCMG ADK board (ATmega2560 firmware)"),
        ("VERSION", ident.version),
        ("URI", ident.uri),
        ("SERIAL", "ADK0001"),
    ):
        h.append(f'#define IDENTITY_{name} "{value}"')
    curve = cfg.power.battery.ocv_curve
    h += [
        "",
        "/* LiPo open-circuit volts per cell against state of charge (BatteryParams.ocv_curve). */",
        f"#define LIPO_OCV_POINTS {len(curve)}u",
        "#define LIPO_OCV_SOC {" + ", ".join(c_float(f32(s)) for s, _ in curve) + "}",
        "#define LIPO_OCV_V {" + ", ".join(c_float(f32(v)) for _, v in curve) + "}",
        "",
        "#endif /* BOARD_GEN_H */",
        "",
    ]
    return "\n".join(h)
