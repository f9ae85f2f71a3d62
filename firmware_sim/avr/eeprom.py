"""The firmware's EEPROM: the board configuration block and the per-unit calibration slots.

The board reads its configuration at boot from the block at address 0; without a valid block (erased,
damaged, wrong version) it runs on the defaults of :class:`firmware_sim.board.config.BoardConfig`, which the
code generator compiles into the firmware, and says so in a ``Log``. A lab writes a block to a real
board with avrdude (``python -m firmware_sim.avr.eeprom --out board.eep`` then
``avrdude ... -U eeprom:w:board.eep:r``); the simavr harness loads the same image.

Block layout (little-endian; :data:`CONFIG_FIELDS` is the single definition, the C offsets are generated
from it)::

    u16 magic 0x4342 ("BC")  u8 version  u8 n_units  f32 frame_rate_hz ... u8 link  char[24] serial  u16 crc

``crc`` is CRC-16/CCITT-FALSE of every byte before it. Calibration sets (``UnitCalibration.to_bytes()``)
live from :data:`CAL_BASE` in one slot per unit of :func:`cal_slot_size` bytes (the rest of the EEPROM
shared by the configured units, at most a set's maximum size); an erased slot (first byte 0xFF) means
"the default calibration", a damaged one "no calibration" (ARM is refused).
"""

from __future__ import annotations

import argparse
import struct
import sys
from collections.abc import Collection, Sequence
from dataclasses import dataclass, replace

from hil.files.output import OutputError, replace_file
from protocol.calibration import MAX_SIZE as CAL_MAX_SIZE
from protocol.calibration.checks import f32
from protocol.crc import crc16_ccitt_false
from protocol.errors import ConfigError

from ..board.config import LIPO_OCV_CURVE, BoardConfig

EEPROM_SIZE = 4096
CONFIG_MAGIC = 0x4342
CONFIG_VERSION = 3
"""3: the ``link`` byte (version 2 blocks, without it, are refused: the defaults run until rewritten)."""
MAX_HW_UNITS = 6
"""Twelve hardware output-compare channels (Timers 1, 3, 4, 5) drive at most six units."""
SERIAL_LEN = 24

# (name, struct code, where the value comes from in BoardConfig: a dotted path or a constant)
CONFIG_FIELDS: tuple[tuple[str, str, str], ...] = (
    ("magic", "H", "=magic"),
    ("version", "B", "=version"),
    ("n_units", "B", "n_units"),
    ("frame_rate_hz", "f", "frame_rate_hz"),
    ("telemetry_rate_hz", "f", "telemetry_rate_hz"),
    ("heartbeat_rate_hz", "f", "heartbeat_rate_hz"),
    ("link_timeout_s", "f", "link_timeout_s"),
    ("mcu_watchdog_s", "f", "mcu_watchdog_s"),
    ("rotor_safe_us", "H", "rotor_safe_us"),
    ("ppm", "B", "ppm"),
    ("cells", "B", "power.battery.cells"),
    ("battery_resistance_ohm", "f", "power.battery.internal_resistance_ohm"),
    ("warn_v_cell", "f", "power.thresholds.warn_v_cell"),
    ("limit_v_cell", "f", "power.thresholds.limit_v_cell"),
    ("shed_v_cell", "f", "power.thresholds.shed_v_cell"),
    ("hysteresis_v_cell", "f", "power.thresholds.hysteresis_v_cell"),
    ("limit_throttle", "f", "power.thresholds.limit_throttle"),
    ("brownout_release_v", "f", "power.thresholds.brownout_release_v"),
    ("filter_time_constant_s", "f", "power.thresholds.filter_time_constant_s"),
    ("power_update_period_s", "f", "power.update_period_s"),
    ("ubec_current_limit_a", "f", "power.ubec.current_limit_a"),
    ("esc_supply_switch", "B", "esc_supply_switch"),
    ("baud", "I", "=baud"),
    ("link", "B", "=link"),
    ("serial", f"{SERIAL_LEN}s", "identity.serial"),
)
DEFAULT_BAUD = 115200
"""UART0 speed; 16 MHz with double speed also gives 250000, 500000 and 1000000 baud exactly."""
UART_CLOCK_HZ = 16_000_000
"""The clock UART0 divides down to its baud rate (the ATmega2560's F_CPU)."""
MAX_BAUD_ERROR_PERMILLE = 25
"""How far (‰) the rate UART0 can make may lie from the rate asked for. The divisor is whole, so most
rates come out off: 115200 (the default) at +2.1 %, which a USB-serial bridge takes; 230400 at -3.5 %,
921600 at +8.5 % (it runs at 1 Mbaud), where the host reads garbage and the board, which cannot say so
on that line, looks dead. A block asking for such a rate is refused, by the image builder and by the
firmware (firmware/src/config.c: defaults, and a Log on a link that works)."""
LINKS = ("uart", "usb", "first")
"""Which link the host's protocol runs on (the ``link`` byte is the index): ``uart`` = UART0 (the default,
the Mega ADK's USB-serial port), ``usb`` = the phone over the Mega ADK's USB host port (Android Open
Accessory, firmware/src/aoa.c), ``first`` = both listened to until one delivers a valid frame, which then
is the link until the next reset. Like ``baud`` this is ADK hardware configuration, so it lives in the
EEPROM block only and not in :class:`BoardConfig`: the Python board emulator speaks on its pty alone."""
DEFAULT_LINK = "uart"
CONFIG_STRUCT = struct.Struct("<" + "".join(code for _, code, _ in CONFIG_FIELDS) + "H")
CONFIG_SIZE = CONFIG_STRUCT.size
CAL_BASE = 128
BOOT_COUNT_BASE = 112
BOOT_COUNT_SLOTS = 4
"""The boot counter: ``BOOT_COUNT_SLOTS`` little-endian u32 slots from ``BOOT_COUNT_BASE``, between the
configuration block and the calibration slots. At every boot the firmware takes the largest count in
them (an erased slot, 0xFFFFFFFF, holds none; all erased: 0), adds one and writes it into slot
``count % BOOT_COUNT_SLOTS`` before it sends anything: each slot is written once every four boots (an
EEPROM cell takes ~100 000 writes: 400 000 boots), and a reset during the write leaves the other slots'
counts. The boot id the board announces is :func:`boot_id` of that count."""
assert CONFIG_SIZE <= BOOT_COUNT_BASE and BOOT_COUNT_BASE + 4 * BOOT_COUNT_SLOTS <= CAL_BASE


def cal_slot_size(n_units: int) -> int:
    """Bytes of EEPROM per unit's calibration slot on a board with ``n_units`` units."""
    return min(CAL_MAX_SIZE, (EEPROM_SIZE - CAL_BASE) // n_units)


def field_offsets() -> dict[str, int]:
    """Byte offset of every field in the block (the codegen turns these into C macros)."""
    offsets, at = {}, 0
    for name, code, _ in CONFIG_FIELDS:
        offsets[name] = at
        at += struct.calcsize("<" + code)
    offsets["crc"] = at
    return offsets


def _value(cfg: BoardConfig, source: str, baud: int, link: str) -> object:
    if source == "=link":
        return LINKS.index(link)
    if source == "=magic":
        return CONFIG_MAGIC
    if source == "=version":
        return CONFIG_VERSION
    if source == "=baud":
        return baud
    value: object = cfg
    for part in source.split("."):
        value = getattr(value, part)
    return value


FIRMWARE_RAIL_TOP_READING_V = (1023 * 2560 // 1024 * 5 // 2) / 1000
"""V: the highest UBEC rail voltage the firmware's ADC reports (6.392 V): the top count of its 2.56 V
reference behind the rail's 2/5 divider, in adc.c's integers (``firmware/include/adc.h``:
``ADC_UBEC_MAX_MV``). The board leaves brown-out only once the rail it reads reaches the release level:
the firmware refuses a block whose release is above this (config.c), as :func:`check_hardware` does."""


def check_hardware(cfg: BoardConfig) -> None:
    """Raise :class:`ConfigError` for what the BoardConfig allows but the ADK firmware cannot do."""
    cfg.validate()
    _check_power_period(cfg.power.update_period_s)
    if tuple(tuple(point) for point in cfg.power.battery.ocv_curve) != LIPO_OCV_CURVE:
        raise ConfigError(
            "the firmware's discharge curve is compiled in (LIPO_OCV_CURVE, board_gen.h) and the block has "
            "no room for another: it would judge this pack's charge and stages by that curve",
            "BoardConfig.power.battery.ocv_curve",
        )
    _check_as_float32(cfg)
    if cfg.n_units > MAX_HW_UNITS:
        raise ConfigError(
            f"{cfg.n_units} units; the ADK has {2 * MAX_HW_UNITS} hardware pulse channels",
            "BoardConfig.n_units",
        )
    if cfg.ppm and cfg.n_units > 4:
        raise ConfigError("PPM-sum needs Timer5, free only with 4 units or fewer", "BoardConfig.ppm")
    if not cfg.identity.serial.isascii():
        raise ConfigError("the board serial must be ASCII", "BoardConfig.identity.serial")
    if "\0" in cfg.identity.serial:
        # the firmware reads the serial up to its first NUL (config.c): "LAB", NUL, "07" went out as "LAB"
        raise ConfigError(
            "the board serial must hold no NUL: the firmware reads it up to the first one",
            "BoardConfig.identity.serial",
        )
    # the firmware's ADC range, where the scenario reader refuses the same (imported here: the scenario
    # package is ~0.1 s of imports no EEPROM tool needs otherwise)
    from hil.scenario.reader import CELL_FULL_V, FIRMWARE_BATTERY_FULL_SCALE_V, FIRMWARE_MAX_CELLS

    release_v = cfg.power.thresholds.brownout_release_v
    if not release_v <= FIRMWARE_RAIL_TOP_READING_V:
        raise ConfigError(
            f"a brown-out release of {release_v:g} V is above the {FIRMWARE_RAIL_TOP_READING_V:g} V the "
            "firmware's ADC reads on the UBEC rail: the board would never leave brown-out",
            "BoardConfig.power.thresholds.brownout_release_v",
        )
    cells = cfg.power.battery.cells
    if cells > FIRMWARE_MAX_CELLS:
        raise ConfigError(
            f"{cells} cells are {cells * CELL_FULL_V:g} V full, beyond the "
            f"{FIRMWARE_BATTERY_FULL_SCALE_V:g} V the firmware's ADC reads: "
            f"at most {FIRMWARE_MAX_CELLS} cells",
            "BoardConfig.power.battery.cells",
        )


def _check_power_period(period_s: float) -> None:
    """The firmware takes a power period of whole milliseconds only (config.c's ``whole_ms``): its power
    manager runs on its millisecond clock (app.c's ``next_power_ms``). The emulator's 0.1 ms floor was a
    block the firmware refused, and 1.5 ms one it ran every 2 ms while its battery filter's gain assumed
    1.5 ms. Checked on the float32 the block holds, in the firmware's arithmetic (a float32 times 1000 is
    exact in double, and f32() rounds it once)."""
    ms = f32(f32(period_s) * 1000.0)
    if ms < 1.0 or abs(ms - round(ms)) > f32(1e-3):
        raise ConfigError(
            f"{period_s:g} s is not a whole number of milliseconds, 1 at least: the firmware runs its power "
            "manager on its millisecond clock",
            "BoardConfig.power.update_period_s",
        )


def _check_as_float32(cfg: BoardConfig) -> None:
    """The firmware checks the block's float32 values in float32 arithmetic (config.c's ``parse``); a rule
    ``BoardConfig.validate`` passes in double can fail there, and the firmware then runs on its defaults.
    Single bounds cannot flip (rounding keeps order), but strict ones and sums can: a threshold under
    float32's smallest (1e-300 V) is stored as 0, two thresholds 1e-12 V apart are stored equal, a warn
    level plus hysteresis a hair under a full cell rounds onto it."""
    t = cfg.power.thresholds
    where = "BoardConfig.power.thresholds"
    warn, limit, shed = f32(t.warn_v_cell), f32(t.limit_v_cell), f32(t.shed_v_cell)
    if not warn > limit > shed > 0.0:
        raise ConfigError(
            f"stored as float32 they are {warn!r}, {limit!r}, {shed!r} V: the firmware needs "
            "warn_v_cell > limit_v_cell > shed_v_cell > 0 in the values it reads",
            where,
        )
    full_cell_v = f32(LIPO_OCV_CURVE[-1][1])
    # the float32 sum: both operands are float32 and within 2^29 of each other's scale, so their double sum
    # is exact (or, for a negligible hysteresis, rounds to warn alike) and f32() rounds it once, as the FPU
    cleared_v = f32(warn + f32(t.hysteresis_v_cell))
    if not cleared_v < full_cell_v:
        raise ConfigError(
            f"warn_v_cell + hysteresis_v_cell is {cleared_v!r} V in the firmware's float32, not below its "
            f"full cell ({full_cell_v!r} V): the stage would never clear",
            f"{where}.warn_v_cell",
        )
    if not f32(t.brownout_release_v) > 0.0:
        raise ConfigError(
            f"{t.brownout_release_v!r} V is stored as float32 0: the board would never enter brown-out",
            f"{where}.brownout_release_v",
        )


def uart_baud(baud: int) -> int:
    """The rate (baud, whole) UART0 runs at when asked for ``baud``: double speed, the divisor rounded to
    the nearest whole one — in the firmware's integers (firmware/src/config.c: ``baud_made``), so the two
    draw the line at the same rates."""
    return UART_CLOCK_HZ // (8 * ((UART_CLOCK_HZ + 4 * baud) // (8 * baud)))


def config_block(cfg: BoardConfig, baud: int = DEFAULT_BAUD, link: str = DEFAULT_LINK) -> bytes:
    """The EEPROM bytes of ``cfg`` (validated for this hardware) with the UART at ``baud`` and the host's
    protocol on ``link`` (one of :data:`LINKS`)."""
    check_hardware(cfg)
    if not 9600 <= baud <= 1_000_000:
        raise ConfigError(f"{baud} baud is outside 9600..1000000", "baud")
    made = uart_baud(baud)
    if abs(made - baud) * 1000 > baud * MAX_BAUD_ERROR_PERMILLE:
        raise ConfigError(
            f"{baud} baud: UART0 ({UART_CLOCK_HZ / 1e6:g} MHz) makes {made} baud, "
            f"{(made / baud - 1) * 100:+.1f} %, beyond the ±{MAX_BAUD_ERROR_PERMILLE / 10:g} % a serial "
            f"link bears (exact: 250000, 500000, 1000000)",
            "baud",
        )
    if link not in LINKS:
        raise ConfigError(f"link {link!r} is not one of {', '.join(LINKS)}", "link")
    values = []
    for _, code, source in CONFIG_FIELDS:
        v = _value(cfg, source, baud, link)
        if code.endswith("s"):
            raw = str(v).encode("ascii")
            v = raw.ljust(SERIAL_LEN, b"\0")
        elif code == "f":
            v = float(v)  # type: ignore[arg-type]
        else:
            v = int(v)  # type: ignore[call-overload]
        values.append(v)
    body = CONFIG_STRUCT.pack(*values, 0)[:-2]
    return body + struct.pack("<H", crc16_ccitt_false(body))


_NOT_COMPARED = frozenset({"magic", "version", "baud", "serial"})
"""Block fields :func:`config_mismatch` passes over: the block's own framing, and the lab's wiring and
identity (a board keeps its serial and its UART speed whatever it is asked to drive)."""


def stored_config(image: bytes) -> dict[str, object] | None:
    """The fields of ``image``'s configuration block by name (:data:`CONFIG_FIELDS`), or None when the
    firmware would not take the block (erased, damaged, another version) and runs on its defaults."""
    if len(image) < CONFIG_SIZE:
        return None
    names = [name for name, _, _ in CONFIG_FIELDS]
    fields = dict(zip([*names, "crc"], CONFIG_STRUCT.unpack_from(image), strict=True))
    if (
        fields["magic"] != CONFIG_MAGIC
        or fields["version"] != CONFIG_VERSION
        or fields["crc"] != crc16_ccitt_false(image[: CONFIG_SIZE - 2])
    ):
        return None
    return fields


def config_mismatch(
    image: bytes, cfg: BoardConfig, link: str, only: Collection[str] | None = None
) -> str | None:
    """What the firmware booted on ``image`` runs with that differs from ``cfg`` with the host's protocol
    on ``link`` (None: nothing that matters), among the block fields ``only`` (None: all but
    :data:`_NOT_COMPARED`). Why: an existing EEPROM file keeps its own configuration, while a driver that
    steps the firmware (a world, the pulse record) reads its channels, frames and battery from ``cfg``; a
    file of another board (two units under a world of four) drove the world's units from the wrong
    channels, silently, and a file whose firmware listens on the phone's USB link, served on UART0, was a
    board that never answered. A block the firmware would not take is compared as the defaults it runs
    on instead; a stored link ``first`` listens on both, so it matches either."""
    stored = stored_config(image)
    source = "its configuration block"
    if stored is None:
        stored = stored_config(config_block(BoardConfig()))
        source = "no valid configuration block: the firmware's defaults"
    wanted = stored_config(config_block(cfg, link=link))
    assert stored is not None and wanted is not None  # blocks config_block made are valid
    for name, _, _ in CONFIG_FIELDS:
        if name in _NOT_COMPARED or (only is not None and name not in only) or stored[name] == wanted[name]:
            continue
        if name == "link" and stored[name] == LINKS.index("first"):
            continue
        have, want = _shown(name, stored[name]), _shown(name, wanted[name])
        return f"{name} = {have} ({source}), {want} here"
    return None


def _shown(name: str, value: object) -> str:
    """A block field's value as a person reads it: floats short, the link by its name."""
    if name == "link" and isinstance(value, int) and value < len(LINKS):
        return LINKS[value]
    return f"{value:g}" if isinstance(value, float) else str(value)


@dataclass(frozen=True)
class EepromImage:
    """A whole EEPROM: the configuration block and, per unit, a calibration set or None (erased slot)."""

    config: BoardConfig
    calibrations: tuple[bytes | None, ...] = ()
    baud: int = DEFAULT_BAUD
    link: str = DEFAULT_LINK

    def to_bytes(self) -> bytes:
        image = bytearray(b"\xff" * EEPROM_SIZE)
        block = config_block(self.config, self.baud, self.link)
        image[: len(block)] = block
        if len(self.calibrations) > self.config.n_units:
            raise ConfigError(
                f"{len(self.calibrations)} calibration sets for {self.config.n_units} units", "EepromImage"
            )
        slot = cal_slot_size(self.config.n_units)
        for unit, data in enumerate(self.calibrations):
            if data is None:
                continue
            if len(data) > slot:
                raise ConfigError(f"{len(data)} bytes > slot of {slot}", f"EepromImage.calibrations[{unit}]")
            start = CAL_BASE + unit * slot
            image[start : start + len(data)] = data
        return bytes(image)


def read_boot_count(image: bytes) -> int:
    """The boot counter of an EEPROM image: the count of the board's last boot (0: never booted)."""
    counts = struct.unpack_from(f"<{BOOT_COUNT_SLOTS}I", image, BOOT_COUNT_BASE)
    return max((c for c in counts if c != 0xFFFFFFFF), default=0)


def boot_id(count: int, serial: str) -> int:
    """The boot id the firmware announces for boot ``count`` (``HelloReply.boot_id``, ``Heartbeat.boot_id``):
    the count, its upper half XORed with the CRC-16 of the board's serial — two boards with other serials
    and the same count announce other ids; one board's ids repeat only after 2^32 boots. 0 (no boot id)
    for the one count that would give it: the firmware then counts on to the next boot."""
    return (count ^ (crc16_ccitt_false(serial.encode("utf-8")[:SERIAL_LEN]) << 16)) & 0xFFFFFFFF


def read_calibration(image: bytes, n_units: int, unit: int) -> bytes | None:
    """The calibration set stored for ``unit`` in the EEPROM image of an ``n_units`` board (None: erased)."""
    size = cal_slot_size(n_units)
    start = CAL_BASE + unit * size
    slot = image[start : start + size]
    if not slot or slot[0] == 0xFF:
        return None
    counts = slot[24:28]
    return bytes(slot[: 28 + 12 * sum(counts) + 2])


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m firmware_sim.avr.eeprom",
        description="Write an EEPROM image (board configuration) for the ADK firmware.",
        epilog="examples:\n"
        "  python -m firmware_sim.avr.eeprom --out board.eep --units 3 --frame-rate 100 --serial LAB-07\n"
        "  avrdude -p m2560 -c wiring -P /dev/ttyACM0 -b 115200 -U eeprom:w:board.eep:r\n",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--out", required=True, help="file to write (raw binary, 4096 bytes)")
    p.add_argument("--units", type=int, default=4, help="VSCMG units (1..6)")
    p.add_argument("--frame-rate", type=float, default=50.0, help="pulse frame rate, 50..490 Hz")
    p.add_argument("--telemetry-rate", type=float, default=20.0, help="telemetry rate, Hz")
    p.add_argument("--link-timeout", type=float, default=0.25, help="link watchdog, s")
    p.add_argument("--mcu-watchdog", type=float, default=0.5, help="MCU watchdog, s")
    p.add_argument("--cells", type=int, default=3, help="battery cells in series")
    p.add_argument("--ppm", action="store_true", help="also output a PPM-sum train (4 units or fewer)")
    p.add_argument(
        "--esc-supply-switch",
        action="store_true",
        help="the ESC supply cut switch is wired (pin D22): ESC endpoint programming power-cycles the ESC",
    )
    p.add_argument("--serial", default="ADK0001", help="board serial number (ASCII, <= 24 bytes)")
    p.add_argument(
        "--link",
        choices=LINKS,
        default=DEFAULT_LINK,
        help="where the host's protocol runs: UART0, the phone over USB (AOA), or the first to speak",
    )
    args = p.parse_args(argv)
    base = BoardConfig()
    try:
        cfg = base.replace(
            n_units=args.units,
            frame_rate_hz=args.frame_rate,
            telemetry_rate_hz=args.telemetry_rate,
            link_timeout_s=args.link_timeout,
            mcu_watchdog_s=args.mcu_watchdog,
            ppm=args.ppm,
            esc_supply_switch=args.esc_supply_switch,
            identity=replace(base.identity, serial=args.serial),
            power=replace(base.power, battery=replace(base.power.battery, cells=args.cells)),
        )
        data = EepromImage(cfg, link=args.link).to_bytes()
        # whole or not at all, and a refusal (a missing folder, a folder there, a full disk) said as one
        # line naming --out: an open() here was an OSError's traceback, status 1
        replace_file(args.out, lambda f: f.write(data))
    except ConfigError as exc:
        sys.stderr.write(f"error: {exc}\n")
        return 2
    except OutputError as exc:
        sys.stderr.write(f"error: --out: {exc}\n")
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
