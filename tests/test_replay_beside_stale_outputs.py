"""``hil replay`` into a folder an earlier replay wrote, and its board options without a board.

A replay with ``--no-plots`` into the ``--out`` of an earlier one kept that one's figures beside its own
summary (attitude.png and rates.png of another window, or another log): now a replay removes what a
replay writes there first (only those files). And without ``--port``, ``--scenario`` and ``--lockstep``
were taken and ignored — a scenario file that did not exist replayed, status 0: now each is refused,
naming the option, as ``hil run`` refuses ``--phone`` without ``--port``.
"""

from __future__ import annotations

import subprocess
import sys

import pytest

from hil.logs.replay import REPLAY_OUTPUTS
from hil.scenario.paths import FIXTURES

SIMULATED = FIXTURES / "logs" / "simulated_testbed_4s.csv"


def _replay(*argv: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "hil", "replay", str(SIMULATED), *argv],
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_a_replay_without_plots_leaves_no_earlier_replays_figures(tmp_path):
    out = tmp_path / "out"
    first = _replay("--out", str(out))
    assert first.returncode == 0, first.stderr[-2000:]
    drawn = {p.name for p in out.iterdir()}
    assert {"attitude.png", "rates.png", "estimates.csv", "summary.json"} <= drawn
    assert drawn <= set(REPLAY_OUTPUTS)  # every file a replay writes is one it knows to clear
    (out / "notes.txt").write_text("mine\n")  # not a replay's: kept
    second = _replay("--out", str(out), "--no-plots", "--window", "0", "2")
    assert second.returncode == 0, second.stderr[-2000:]
    assert sorted(p.name for p in out.iterdir()) == ["estimates.csv", "notes.txt", "summary.json"]
    assert (out / "notes.txt").read_text() == "mine\n"


@pytest.mark.parametrize(
    "given",
    [
        ["--scenario", "no-such-scenario.toml"],
        ["--scenario", "cubesat-1u"],
        ["--lockstep"],
    ],
)
def test_a_board_option_without_a_port_is_refused_not_ignored(tmp_path, given):
    out = tmp_path / "out"
    done = _replay("--out", str(out), "--no-plots", *given)
    assert done.returncode == 2, done.stdout[-2000:]
    assert f"{given[0]}: with --port only" in done.stderr and "Traceback" not in done.stderr
    assert not out.exists()  # nothing replayed
