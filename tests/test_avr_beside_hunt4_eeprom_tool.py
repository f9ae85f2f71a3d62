"""``python -m firmware_sim.avr.eeprom --out PATH`` (the image a lab writes to a real board with avrdude)
given a PATH it cannot write: one line naming ``--out`` and the path, status 2, nothing left behind.

It opened PATH itself, so a path in a missing folder, a folder's path, or a path under a file was an
``OSError``'s traceback and status 1 (what a bad option never is: docs/firmware_sim.md, "Running it").
No toolchain is needed: the image is written in Python.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from firmware_sim.avr.eeprom import EEPROM_SIZE, stored_config

ROOT = Path(__file__).resolve().parents[1]


def _eeprom_tool(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "firmware_sim.avr.eeprom", *args],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
    )


@pytest.mark.parametrize(
    ("make", "said"),
    [
        (lambda tmp: tmp / "missing-folder" / "board.eep", "No such file or directory"),
        (lambda tmp: tmp, "Is a directory"),
        (lambda tmp: (tmp / "a-file").write_text("x") and tmp / "a-file" / "board.eep", "Not a directory"),
    ],
    ids=["in-a-missing-folder", "a-folder", "under-a-file"],
)
def test_an_out_path_that_cannot_be_written_is_one_line_naming_it(tmp_path, make, said):
    path = make(tmp_path)
    before = sorted(p.name for p in tmp_path.iterdir())
    done = _eeprom_tool("--out", str(path), "--units", "3")
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr, done.stderr
    lines = [line for line in done.stderr.splitlines() if "RuntimeWarning" not in line]
    assert lines == [f"error: --out: cannot write {path}: {said}"], done.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # no temporary left beside it


def test_an_existing_file_is_replaced_by_a_whole_image(tmp_path):
    path = tmp_path / "board.eep"
    path.write_bytes(b"an older, longer file " * 400)
    done = _eeprom_tool("--out", str(path), "--units", "3")
    assert done.returncode == 0, done.stderr
    image = path.read_bytes()
    assert len(image) == EEPROM_SIZE
    stored = stored_config(image)
    assert stored is not None and stored["n_units"] == 3
