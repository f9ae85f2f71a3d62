"""A configuration block asking for a baud rate UART0 cannot make is refused, by the image builder and by
the firmware, instead of giving a link that only carries garbage.

UART0 divides its 16 MHz clock by a whole number, so most rates come out off: 115200 at +2.1 % (what every
Arduino runs), but 230400 at -3.5 % and 921600 — a standard rate — at +8.5 % (the divisor rounds to
1 Mbaud). Both ends accepted any rate in 9600..1000000: the image builder wrote 921600 into the block and
the firmware ran UART0 at 1 Mbaud, where a host at 921600 reads only damaged frames and the board, unable
to say anything on that line, looks dead. Now a rate off by more than ``MAX_BAUD_ERROR_PERMILLE`` is a
``ConfigError`` naming ``baud`` in the builder, and in the firmware a refused block (defaults, 115200, and
the boot Log saying why).
"""

from __future__ import annotations

import struct

import hypothesis.strategies as st
import pytest
from conformance.host import SerialHost
from hypothesis import example, given, settings

from firmware_sim.avr import AvrBoard, eeprom
from firmware_sim.avr.hostlib import config_parse
from firmware_sim.board.config import BoardConfig
from protocol.crc import crc16_ccitt_false
from protocol.errors import ConfigError
from protocol.messages import Log

F_CPU = 16_000_000
BAD_BAUD_PROBLEM = 20  # config.c: the index of "baud" in its problem names


def made(baud: int) -> float:
    """The datasheet's rate for UBRR rounded to the nearest (double speed): F_CPU / (8 (UBRR + 1))."""
    ubrr = round(F_CPU / (8 * baud) - 1)
    return F_CPU / (8 * (ubrr + 1))


def block_with_baud(baud: int) -> bytes:
    """The default configuration block with ``baud`` patched in and its CRC made good (by hand, as a
    block written by another tool or by an older builder would be)."""
    body = bytearray(eeprom.config_block(BoardConfig())[:-2])
    struct.pack_into("<I", body, eeprom.field_offsets()["baud"], baud)
    return bytes(body) + struct.pack("<H", crc16_ccitt_false(bytes(body)))


bauds = st.one_of(
    st.sampled_from([9600, 19200, 38400, 57600, 115200, 230400, 250000, 460800, 500000, 921600, 1_000_000]),
    st.integers(9600, 1_000_000),
)


@settings(max_examples=200, deadline=None)
@given(baud=bauds)
@example(baud=921600)
@example(baud=230400)
def test_the_image_builder_writes_only_a_rate_the_uart_makes(baud):
    good = abs(made(baud) / baud - 1) <= 0.025
    if good:
        assert (
            struct.unpack_from(
                "<I", eeprom.config_block(BoardConfig(), baud=baud), eeprom.field_offsets()["baud"]
            )[0]
            == baud
        )
    else:
        with pytest.raises(ConfigError, match="baud") as err:
            eeprom.config_block(BoardConfig(), baud=baud)
        assert err.value.where == "baud"


@pytest.mark.firmware
@settings(max_examples=200, deadline=None)
@given(baud=bauds)
@example(baud=921600)
@example(baud=115200)
def test_the_firmware_takes_the_rates_the_builder_writes_and_no_other(baud):
    try:
        eeprom.config_block(BoardConfig(), baud=baud)
        builder_ok = True
    except ConfigError:
        builder_ok = False
    status, got, problem = config_parse(block_with_baud(baud))
    if builder_ok:
        assert (status, got["baud"]) == (0, baud)
    else:
        assert (status, problem) == (3, BAD_BAUD_PROBLEM), f"{baud} baud: the firmware took it"
        assert got["baud"] == eeprom.DEFAULT_BAUD


@pytest.mark.firmware
def test_the_firmware_on_simavr_refuses_a_block_at_921600_baud_and_says_so():
    image = bytearray(eeprom.EepromImage(BoardConfig()).to_bytes())
    image[: eeprom.CONFIG_SIZE] = block_with_baud(921600)
    with AvrBoard(BoardConfig(), eeprom_image=bytes(image)) as board:
        host = SerialHost(board.port)
        try:
            host.handshake()
            board.press_reset()  # the boot reports go out at boot: reset with the host listening
            host.handshake()
            host.poll(0.2)
            said = [m.text for m in host.received if isinstance(m, Log) and "configuration" in m.text]
        finally:
            host.close()
        board.check()
    assert any("refused (baud)" in s and "defaults" in s for s in said), said
