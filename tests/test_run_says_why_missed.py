"""A run that ends off its target says why on its last lines, not only "NOT met" beside the settle time:
``hil run`` printed ``exit completed`` and the reasons (summary.json's ``requirement.why``: the operator,
the faults, the link, a slew started too late for the run's end) were in the file alone. Through the real
command, a run cut before its slew could end; and the lines for summaries a run does not write."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from hil.cli.run import REQUIREMENT_SHOWN, requirement_lines


def test_a_run_cut_before_its_slew_ends_says_why_it_missed(tmp_path: Path) -> None:
    done = subprocess.run(
        [sys.executable, "-m", "hil", "run", "--no-plots", "--duration", "12", "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    (summary,) = tmp_path.glob("*/summary.json")
    why = json.loads(summary.read_text())["requirement"]["why"]
    said = [line for line in done.stdout.splitlines() if line.startswith("requirement")]
    assert said == [f"requirement       NOT met: {why}"]
    assert "before the end" in why


def test_a_met_unknown_or_damaged_requirement_says_nothing_and_a_long_one_is_cut() -> None:
    assert requirement_lines({"requirement": {"met": True, "why": None}}) == []
    assert requirement_lines({}) == []
    assert requirement_lines({"requirement": "NOT met"}) == []
    assert requirement_lines({"requirement": {"met": False, "why": 3}}) == []
    (line,) = requirement_lines({"requirement": {"met": False, "why": "x" * 10_000}})
    assert len(line) < REQUIREMENT_SHOWN + 100 and line.endswith("(summary.json holds the rest)")
