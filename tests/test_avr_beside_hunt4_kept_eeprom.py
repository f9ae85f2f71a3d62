"""An ``--eeprom`` file kept from another board, under a world that steps the firmware.

An existing EEPROM file keeps its own configuration block (docs/firmware_sim.md, "The real firmware"), so
the firmware boots on the file's board; the stepped board (``firmware-sim --avr --world``,
``FirmwareBoard``) reads its pulse channels, frame period and battery from the world's configuration. A
file saved by a two-unit board, given to ``firmware-sim --avr --world paper-testbed`` (three units), was
served with status 0: the firmware drove two units' channels while the world's third unit got no pulse,
and firmware-sim's banner said three units. A block the firmware would not take (damaged) made it run on
its four-unit defaults, just as silently. Both are now refused before the harness starts, naming the file
and the field, the file left as it was; an image the same world saved is taken again.
"""

from __future__ import annotations

import hashlib
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from firmware_sim.avr import eeprom
from firmware_sim.avr.harness import HarnessOptions
from firmware_sim.avr.stepped import FirmwareBoard
from firmware_sim.board.config import BoardConfig
from protocol.errors import ConfigError

pytestmark = pytest.mark.firmware

ROOT = Path(__file__).resolve().parents[1]
WORLD_UNITS = 3
"""paper-testbed's spacecraft: a 3-unit tetrahedron."""


def _firmware_sim(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "firmware_sim", "--duration", "1", *args],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=ROOT,
    )


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_firmware_sim_refuses_a_kept_eeprom_of_another_board_under_a_world(tmp_path):
    path = tmp_path / "two-units.eep"
    path.write_bytes(eeprom.EepromImage(BoardConfig(n_units=2)).to_bytes())
    before = _digest(path)
    done = _firmware_sim("--avr", "--world", "paper-testbed", "--eeprom", str(path))
    assert done.returncode == 2, done.stderr
    assert f"--eeprom {path}" in done.stderr and "n_units = 2" in done.stderr, done.stderr
    assert "Traceback" not in done.stderr and done.stdout == ""
    assert _digest(path) == before


def test_a_damaged_block_is_the_firmwares_defaults_and_refused_when_the_world_differs(tmp_path):
    image = bytearray(eeprom.EepromImage(BoardConfig(n_units=WORLD_UNITS)).to_bytes())
    image[3] ^= 0x01  # n_units: the CRC no longer matches, the firmware runs on its 4-unit defaults
    path = tmp_path / "damaged.eep"
    path.write_bytes(bytes(image))
    done = _firmware_sim("--avr", "--world", "paper-testbed", "--eeprom", str(path))
    assert done.returncode == 2, done.stderr
    assert "firmware's defaults" in done.stderr and "n_units = 4" in done.stderr, done.stderr
    assert path.read_bytes() == bytes(image)


def test_an_image_the_same_world_saved_is_taken_again(tmp_path):
    """The path's other side: calibrations kept in the file persist from one run to the next."""
    path = tmp_path / "board.eep"
    for _ in range(2):
        done = _firmware_sim("--avr", "--world", "paper-testbed", "--eeprom", str(path))
        assert done.returncode == 0, done.stderr
    assert path.stat().st_size == eeprom.EEPROM_SIZE


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    units=st.integers(1, 6),
    frame_rate=st.sampled_from([50.0, 100.0, 200.0]),
    cells=st.integers(2, 4),
    usb=st.booleans(),
)
def test_any_other_kept_board_is_refused_naming_a_field_that_differs(tmp_path, units, frame_rate, cells, usb):
    """A drawn board kept in the file, against the board the world steps (3 units, 50 Hz, 3 cells, UART0):
    whatever differs is named, before any harness starts."""
    base = BoardConfig()
    kept = base.replace(
        n_units=units,
        frame_rate_hz=frame_rate,
        power=replace(base.power, battery=replace(base.power.battery, cells=cells)),
    )
    world = BoardConfig(n_units=WORLD_UNITS)
    assume((units, frame_rate, cells, usb) != (WORLD_UNITS, 50.0, 3, False))
    path = tmp_path / f"kept-{units}-{frame_rate:g}-{cells}-{usb}.eep"
    image = eeprom.EepromImage(kept, link="usb" if usb else "uart").to_bytes()
    path.write_bytes(image)
    with pytest.raises(ConfigError) as caught:
        FirmwareBoard(world, options=HarnessOptions(eeprom_file=path)).close()
    said = str(caught.value)
    assert f"--eeprom {path}" in said, said
    named = {"n_units": units != WORLD_UNITS, "frame_rate_hz": frame_rate != 50.0, "cells": cells != 3,
             "link": usb}  # fmt: skip
    assert any(f"{field} = " in said for field, differs in named.items() if differs), said
    assert path.read_bytes() == image


@pytest.mark.parametrize(
    ("kept", "served"),
    [("usb", ()), ("uart", ("--usb",))],
    ids=["usb-board-on-uart0", "uart-board-on-usb"],
)
def test_the_served_firmware_refuses_a_kept_eeprom_that_listens_on_the_other_link(tmp_path, kept, served):
    """``firmware-sim --avr`` alone keeps the file's configuration (docs/firmware_sim.md), but a board that
    listens on the phone's USB link, served on UART0's pty (or the other way round), never answered a
    host: ``hil run --port`` said "the board did not answer the handshake" after 50 tries, firmware-sim
    status 0 and nothing said."""
    path = tmp_path / f"{kept}.eep"
    path.write_bytes(eeprom.EepromImage(BoardConfig(), link=kept).to_bytes())
    before = _digest(path)
    done = _firmware_sim("--avr", *served, "--eeprom", str(path))
    assert done.returncode == 2, done.stderr
    assert f"--eeprom {path}" in done.stderr and f"link = {kept}" in done.stderr, done.stderr
    assert "Traceback" not in done.stderr and done.stdout == ""
    assert _digest(path) == before


def test_a_kept_board_listening_on_both_links_and_of_other_units_is_still_served(tmp_path):
    """What the served firmware keeps from the file: its units and rates (a lab's board), and a link
    ``first`` that listens on both."""
    path = tmp_path / "first.eep"
    path.write_bytes(eeprom.EepromImage(BoardConfig(n_units=2), link="first").to_bytes())
    done = _firmware_sim("--avr", "--eeprom", str(path))
    assert done.returncode == 0, done.stderr
