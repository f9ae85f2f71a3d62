"""Beside the replug note (test_firmware_usb_replug_reports.py): the counts of what a phone did not get
while no accessory was open are held in a byte (frames lost) and a 16-bit word (reports not sent) that stop
at their ceiling. At 1000 Hz telemetry a phone away for 66 s reached 65535, and the note said "65535 ...
not sent" for the ~80 000 of an 80 s absence, as if exact. A count at its ceiling is now said as a bound
("at least 65535"); below it, the number alone. The firmware under simavr, unpaced, its EEPROM's link USB."""

from __future__ import annotations

import re
import time

import pytest
from conformance.host import SerialHost

from firmware_sim.avr import AvrBoard, eeprom
from firmware_sim.avr.harness import HarnessOptions
from firmware_sim.board.config import BoardConfig
from protocol.messages import Log

pytestmark = pytest.mark.firmware

F_CPU = 16_000_000
NOTE = re.compile(
    r"while no USB accessory was open: (at least )?(\d+) telemetry/heartbeat frames not sent \(stale\), "
    r"(at least )?(\d+) other frames lost"
)
CONFIG = BoardConfig(n_units=1, telemetry_rate_hz=1000.0, heartbeat_rate_hz=1000.0)


def _note_after_absence(away_s: float) -> re.Match[str]:
    """The phone unplugged for `away_s` of board time, then back: the note's match."""
    image = eeprom.EepromImage(CONFIG, link="usb").to_bytes()
    options = HarnessOptions(paced=False, extra_args=("--usb",))
    with AvrBoard(CONFIG, options, eeprom_image=image) as b:
        t0 = int(b.command("usb detach")[0]) / F_CPU
        end = time.monotonic() + 120.0
        while int(b.command("usb nak 0")[0]) / F_CPU - t0 < away_s:
            assert time.monotonic() < end, "the board's clock did not get through the absence"
            time.sleep(0.1)
        host = SerialHost(b.port, clock=b.now)
        try:
            b.command("usb attach")
            log = host.wait_type(Log, 5.0, lambda m: NOTE.match(m.text) is not None)
        finally:
            host.close()
        b.check()
    found = NOTE.match(log.text)
    assert found is not None
    return found


def test_a_count_is_said_as_a_bound_once_it_reached_its_ceiling_and_exactly_below():
    note = _note_after_absence(80.0)  # ~80 000 telemetry frames held back: past the 16-bit ceiling
    assert note.group(1) == "at least ", note.group(0)
    assert int(note.group(2)) == 0xFFFF
    assert note.group(3) is None and int(note.group(4)) == 0  # nothing else was lost: said exactly
    note = _note_after_absence(2.0)
    assert note.group(1) is None, note.group(0)
    assert 1000 <= int(note.group(2)) < 0xFFFF
