"""What docs/firmware_sim.md promises of ``firmware-sim``'s errors, held against the real command.

docs/firmware_sim.md ("Real time" bullet): "A value an option sets that the board refuses is an error naming
the option (``--corrupt: 1.5 is not a probability``), not the code's field." Every fault option keeps that
(``--stall``, ``--noise``, ``--phone-jump``, ``--dead-esc``, ...) except ``--phone-spoof``, whose unknown
kind came out as ``firmware-sim: error: faults.phone_spoof: 'bogus' is not one of ...``: a field of the
code the user never typed. Run through a real subprocess of the console command, as a user meets it.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

# Kinds the world's phone does not know: a typo, a kind in another case, an empty one, a unicode name.
UNKNOWN_KINDS = ["bogus", "HUGE", "", "nän"]


@pytest.mark.parametrize("kind", UNKNOWN_KINDS)
def test_an_unknown_phone_spoof_kind_is_an_error_naming_the_option(kind: str) -> None:
    done = subprocess.run(
        [sys.executable, "-m", "firmware_sim", "--world", "cubesat-1u", "--duration", "1",
         "--phone-spoof", f"1:{kind}"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    assert done.stdout == ""  # no pty was served
    assert "Traceback" not in done.stderr
    last = done.stderr.strip().splitlines()[-1]
    assert last.startswith("firmware-sim: error: --phone-spoof"), last  # the option, not faults.phone_spoof
    assert "faults.phone_spoof" not in last


def test_an_unknown_phone_spoof_kind_in_an_emu_url_names_the_option(tmp_path: Path) -> None:
    """docs/runtime-link.md: ``emu://`` takes firmware-sim's options in its query string, and a value the
    board refuses names the option (``emu://?units=0: cannot open: --units: 0 is outside 1..8``). The
    spoof kind came out as the code's ``faults.phone_spoof`` here too."""
    done = subprocess.run(
        [sys.executable, "-m", "hil", "run", "--port", "emu://?phone_spoof=1:bogus", "--duration", "1",
         "--no-plots", "--out", str(tmp_path / "runs")],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr
    last = done.stderr.strip().splitlines()[-1]
    assert "cannot open: --phone-spoof" in last, last
    assert "faults.phone_spoof" not in last
