"""``hil replay --declination D`` beside ``--lat/--lon/--date``: taken, then ignored.

With a place and date the replay turns its estimates by IGRF-14's declination there; a ``--declination``
given beside them was parsed, bounds-checked and then dropped, the replay ending status 0 with estimates
turned by another declination than the user's and not a word about it (the estimator's inputs are a
declination, one number: two sources of it are a contradiction the user has to settle). Now it is refused
naming the option, before the log is read, with or without ``--port``; each alone works as before.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

FIXTURE = Path(__file__).resolve().parents[1] / "fixtures" / "logs" / "simulated_testbed_4s.csv"
PLACE = ["--lat", "52.52", "--lon", "13.40", "--date", "2019-06-01"]


def _replay(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "hil", "replay", str(FIXTURE), "--no-plots", *args],
        capture_output=True, text=True, timeout=300, cwd=cwd,
    )  # fmt: skip


@settings(
    max_examples=4,
    deadline=None,
    phases=(Phase.explicit, Phase.reuse, Phase.generate),  # each example a subprocess: no shrinking
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(declination=st.floats(-180.0, 180.0), port=st.booleans())
def test_a_declination_beside_a_place_and_date_is_refused_not_ignored(tmp_path_factory, declination, port):
    folder = tmp_path_factory.mktemp("decl")
    board = ["--port", "emu://?units=4"] if port else []
    given_ = [*PLACE, "--declination", repr(declination), *board]
    run = _replay("--out", str(folder / "out"), *given_, cwd=folder)
    assert run.returncode == 2, run.stdout + run.stderr
    assert "hil replay: error: --declination: " in run.stderr and "--lat/--lon/--date" in run.stderr, (
        run.stderr
    )
    assert "Traceback" not in run.stderr
    assert not (folder / "out").exists()  # nothing ran, nothing written


@pytest.mark.parametrize("given_", [PLACE, ["--declination", "7.2"], ["--declination", "0"]])
def test_each_source_of_the_declination_alone_still_replays(tmp_path, given_):
    run = _replay("--out", str(tmp_path / "out"), *given_, cwd=tmp_path)
    assert run.returncode == 0, run.stdout + run.stderr
    said = "IGRF-14 at 52.52, 13.4" if given_ is PLACE else f"declination {float(given_[1]):g} deg"
    assert said in run.stdout, run.stdout
