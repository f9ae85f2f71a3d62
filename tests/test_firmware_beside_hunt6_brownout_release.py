"""A configuration block whose brown-out release level the board's rail can never reach is refused by the
firmware (defaults, and the boot Log naming ``brownout_release_v``), as ``BoardConfig.validate`` refuses it.

The firmware leaves BROWN_OUT only once the rail it measures reaches the release level (app.c's
``power_step``). Its block check took any release in 0..24 V and any pack of 1..12 cells: a release above
what the rail's ADC can report (6.392 V at the top count), at or above a full pack's voltage (the rail is
the pack less the UBEC's dropout), or a one-cell pack under the default 4.5 V release left the board in
BROWN_OUT from power-on for good, every ``Arm`` NACKed ``POWER``, with nothing saying why. A release of 0 V
(or NaN) never entered it at all.
"""

from __future__ import annotations

import dataclasses
import struct

import hypothesis.strategies as st
import numpy as np
import pytest
from conformance.host import SerialHost
from hypothesis import example, given, settings

from firmware_sim.avr import AvrBoard, eeprom
from firmware_sim.avr.hostlib import config_parse
from firmware_sim.board.config import BoardConfig
from protocol.crc import crc16_ccitt_false
from protocol.errors import ConfigError
from protocol.messages import Ack, Arm, Log

BAD_CELLS_PROBLEM = 10  # config.c: the index of "cells" in its problem names
BAD_BROWNOUT_RELEASE_PROBLEM = 15  # config.c: the index of "brownout_release_v"
RAIL_MAX_MV = 1023 * 2560 // 1024 * 5 // 2  # the highest rail adc.c reports (6392 mV)
BATTERY_MAX_MV = 1023 * 2560 // 1024 * 8  # the highest pack adc.c reports (20 456 mV): 4 cells full
RAIL_MAX_V = float(np.float32(RAIL_MAX_MV) * np.float32(0.001))  # as app.c compares it, in float32
FULL_CELL_V = 4.2


def block_with(release_v: float, cells: int) -> bytes:
    """The default configuration block with ``brownout_release_v`` (float32) and ``cells`` patched in and its
    CRC made good by hand, as a block written by another tool or by hand would be."""
    body = bytearray(eeprom.config_block(BoardConfig())[:-2])
    offsets = eeprom.field_offsets()
    struct.pack_into("<f", body, offsets["brownout_release_v"], release_v)
    struct.pack_into("<B", body, offsets["cells"], cells)
    return bytes(body) + struct.pack("<H", crc16_ccitt_false(bytes(body)))


def builder_takes(release_v: float, cells: int) -> bool:
    """Whether the image builder (``BoardConfig.validate``) writes this release and pack."""
    base = BoardConfig()
    power = dataclasses.replace(
        base.power,
        battery=dataclasses.replace(base.power.battery, cells=cells),
        thresholds=dataclasses.replace(base.power.thresholds, brownout_release_v=release_v),
    )
    try:
        eeprom.config_block(dataclasses.replace(base, power=power))
    except ConfigError:
        return False
    return True


releases = st.one_of(
    st.floats(width=32, allow_nan=True, allow_infinity=True),
    st.floats(0.0, 30.0, width=32),
    st.sampled_from([0.0, -0.0, 4.5, 6.392, 6.4, 7.0, 8.4, 24.0]),
)


@pytest.mark.firmware
@settings(max_examples=300, deadline=None)
@given(release_v=releases, cells=st.integers(1, 12))
@example(release_v=7.0, cells=3)  # above what the rail's ADC reports
@example(release_v=4.5, cells=1)  # a one-cell pack never holds the rail at the release
@example(release_v=0.0, cells=3)  # BROWN_OUT never entered
def test_the_firmware_takes_only_a_release_the_rail_can_reach(release_v, cells):
    release_v = struct.unpack("<f", struct.pack("<f", release_v))[0]  # what the block holds
    status, got, problem = config_parse(block_with(release_v, cells))
    readable_pack = 2 <= cells and cells * FULL_CELL_V <= BATTERY_MAX_MV / 1000  # within the battery ADC
    reachable = readable_pack and 0.0 < release_v <= RAIL_MAX_V and release_v < cells * FULL_CELL_V
    why = f"release {release_v!r} V with {cells} cells"
    if reachable:
        assert status == 0, f"{why}: refused ({problem})"
    else:
        assert status == 3 and problem in (BAD_CELLS_PROBLEM, BAD_BROWNOUT_RELEASE_PROBLEM), (
            f"{why}: the firmware took it (status {status}, problem {problem})"
        )
    if builder_takes(release_v, cells):  # what the image builder writes, the firmware takes
        assert status == 0, f"{why}: the image builder writes it, the firmware refused it ({problem})"


@pytest.mark.firmware
def test_the_firmware_on_simavr_refuses_a_release_above_the_rail_and_arms_on_its_defaults():
    image = bytearray(eeprom.EepromImage(BoardConfig()).to_bytes())
    image[: eeprom.CONFIG_SIZE] = block_with(7.0, 3)
    with AvrBoard(BoardConfig(), eeprom_image=bytes(image)) as board:
        host = SerialHost(board.port)
        try:
            host.handshake()
            board.press_reset()  # the boot reports go out at boot: reset with the host listening
            host.handshake()
            host.poll(0.2)
            said = [m.text for m in host.received if isinstance(m, Log) and "configuration" in m.text]
            answer = host.request(Arm())
        finally:
            host.close()
        board.check()
    assert any("refused (brownout_release_v)" in s and "defaults" in s for s in said), said
    assert isinstance(answer, Ack), f"a board held in BROWN_OUT by its release level: {answer}"


@settings(max_examples=200, deadline=None)
@given(release_v=releases, cells=st.integers(2, 4))
@example(release_v=6.4, cells=4)  # above the rail's top reading, below a full 4-cell pack
def test_the_image_builder_refuses_a_release_above_the_rails_top_reading(release_v, cells):
    """``eeprom.config_block`` (``check_hardware``) never writes a release the firmware's rail ADC cannot
    report, whatever else the BoardConfig allows (a UBEC set to 8 V allowed a 7 V release)."""
    base = BoardConfig()
    power = dataclasses.replace(
        base.power,
        battery=dataclasses.replace(base.power.battery, cells=cells),
        ubec=dataclasses.replace(base.power.ubec, set_voltage_v=8.0),
        thresholds=dataclasses.replace(base.power.thresholds, brownout_release_v=release_v),
    )
    config = dataclasses.replace(base, power=power)
    try:
        config.validate()
    except ConfigError:
        return  # refused before the firmware's bounds come in
    if release_v <= eeprom.FIRMWARE_RAIL_TOP_READING_V:
        eeprom.config_block(config)
    else:
        with pytest.raises(ConfigError, match="brownout_release_v|never leave brown-out") as refused:
            eeprom.config_block(config)
        assert refused.value.where == "BoardConfig.power.thresholds.brownout_release_v"
