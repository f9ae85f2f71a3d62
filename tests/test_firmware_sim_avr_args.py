"""``firmware-sim --avr`` given a file that is not what it asks for: one line naming it, status 2, and the
file left as it was.

The harness loads an ``--eeprom`` file's first 4 KiB and saves the board's EEPROM back over it: any
other file given by mistake (a README, a calibration CSV) was cut to 4 KiB, its rest lost, with status 0;
a folder was neither loaded nor saved, without a word; a path in a missing folder was a traceback, and
``--eeprom`` without ``--avr`` was ignored. An ``--avr`` ELF that is no AVR firmware (a text file, the
codec check's ELF) was a ``CalledProcessError`` or a ``KeyError`` traceback.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from pathlib import Path

import pytest

from firmware_sim.avr.eeprom import EEPROM_SIZE

pytestmark = pytest.mark.firmware

ROOT = Path(__file__).resolve().parents[1]


def _firmware_sim(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "firmware_sim", "--duration", "1", *args],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
    )


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.mark.parametrize("size", [1, EEPROM_SIZE - 1, EEPROM_SIZE + 1, 13_988, 100_000])
@pytest.mark.parametrize("served", [(), ("--world", "cubesat-1u")], ids=["served", "stepped-with-a-world"])
def test_an_eeprom_file_of_another_size_is_refused_and_left_as_it_was(tmp_path, size, served):
    """Both ways firmware-sim runs the firmware: served on its pty, and stepped with a world."""
    path = tmp_path / "notes.txt"
    path.write_bytes(os.urandom(size))
    before = _digest(path)
    done = _firmware_sim("--avr", *served, "--eeprom", str(path))
    assert done.returncode == 2, done.stderr
    assert (
        str(path) in done.stderr and "not an EEPROM image" in done.stderr and "Traceback" not in done.stderr
    )
    assert _digest(path) == before


@pytest.mark.parametrize(
    ("make", "said"),
    [
        (lambda tmp: tmp, "not a regular file"),
        (lambda tmp: tmp / "missing-folder" / "board.eep", "is not there"),
    ],
    ids=["a-folder", "a-missing-folder"],
)
def test_an_eeprom_path_that_is_no_file_to_keep_is_refused_naming_it(tmp_path, make, said):
    path = make(tmp_path)
    done = _firmware_sim("--avr", "--eeprom", str(path))
    assert done.returncode == 2 and said in done.stderr and str(path) in done.stderr, done.stderr
    assert "Traceback" not in done.stderr


def test_eeprom_without_avr_is_refused():
    done = _firmware_sim("--eeprom", "/tmp/board.eep")
    assert done.returncode == 2 and "--eeprom" in done.stderr and "--avr" in done.stderr


def test_a_new_or_empty_eeprom_file_is_made_and_kept(tmp_path):
    """The path's other side: a new file (and an empty one) becomes the board's image, and an image the
    board saved is taken again."""
    for path in (tmp_path / "new.eep", tmp_path / "empty.eep"):
        if path.name == "empty.eep":
            path.write_bytes(b"")
        done = _firmware_sim("--avr", "--eeprom", str(path))
        assert done.returncode == 0, done.stderr
        assert path.stat().st_size == EEPROM_SIZE
    again = _firmware_sim("--avr", "--eeprom", str(tmp_path / "new.eep"))
    assert again.returncode == 0, again.stderr


@pytest.mark.parametrize(
    "elf",
    [
        ROOT / "README.md",
        ROOT / "firmware" / "build" / "codec-check.elf",
        Path("/dev/null"),
        Path("/nope.elf"),
    ],
    ids=["text", "another-elf", "dev-null", "missing"],
)
def test_an_avr_elf_that_is_no_board_firmware_is_one_line_naming_it(elf):
    done = _firmware_sim(f"--avr={elf}")
    assert done.returncode == 2, done.stderr
    assert str(elf) in done.stderr and "Traceback" not in done.stderr, done.stderr
