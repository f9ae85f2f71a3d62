"""docs/formats.md: "An empty ``--out`` (``--out "$UNSET"``) is refused by every command (it was the current
directory)." ``hil run``, ``hil replay``, ``hil montecarlo``, ``hil calibrate fit -o``, ``vectors -o`` and
``unit --bench-dir`` refuse it (``hil.cli._parser.given_path``); ``hil calibrate bench --out-dir ""`` and
``hil calibrate sweep --out-dir ""`` did not: ``Path("")`` is ``.``, and they wrote their bench CSVs into
whatever directory the shell was in, status 0. Real subprocesses of the command, in a scratch directory.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

COMMANDS = {
    "bench": ["bench", "--units", "1", "--seed", "1", "--out-dir", ""],
    "sweep": ["sweep", "--port", "emu://", "--unit", "0", "--map", "gimbal_angle", "--out-dir", ""],
}


@pytest.mark.parametrize("action", sorted(COMMANDS))
def test_an_empty_out_dir_is_refused_and_nothing_lands_in_the_current_directory(
    action: str, tmp_path: Path
) -> None:
    done = subprocess.run(
        [sys.executable, "-m", "hil", "calibrate", *COMMANDS[action]],
        capture_output=True, text=True, timeout=300, cwd=tmp_path,
    )  # fmt: skip
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # no bench CSV in the current directory
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr
    assert "--out-dir" in done.stderr and "empty path" in done.stderr, done.stderr
