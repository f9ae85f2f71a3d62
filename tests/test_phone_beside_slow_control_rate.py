"""A controller slower than the host's stale bound, with a phone that streams.

``control_rate_hz = 2`` within ``link_timeout = 1.0`` is a valid scenario (tests/test_scenario_checks.py),
yet every run of it ended "lost: phone" though the simulated phone streamed at ~200 Hz: the host looks at
the phone once a control period (0.5 s), finds half a second of readings each time, and the batched-phone
heuristic (``hil.runtime.phone_cadence``) took each 0.5 s interval for a late batch. Now an interval
counts as a batch only if the host looked in between and found the phone stale.
"""

from __future__ import annotations

import json

import pytest

from hil.cli import main
from hil.scenario.paths import FIXTURES


@pytest.mark.parametrize("rate", [2.0, 2.5])
def test_a_slow_controller_keeps_a_streaming_phone(tmp_path, capsys, rate):
    text = (FIXTURES / "scenarios" / "cubesat-1u.toml").read_text()
    text = text.replace("control_rate_hz = 50.0", f"control_rate_hz = {rate}", 1)
    text = text.replace("link_timeout = 0.25", "link_timeout = 1.0", 1)
    path = tmp_path / "slow.toml"
    path.write_text(text)
    out = tmp_path / "runs"
    status = main(["run", "--scenario", str(path), "--no-plots", "--duration", "5", "--out", str(out)])
    said = capsys.readouterr()
    assert status == 0, said.err[-3000:]
    (run,) = out.iterdir()
    events = [json.loads(line) for line in (run / "events.jsonl").read_text().splitlines() if line.strip()]
    kinds = {e["kind"] for e in events}
    assert "phone_batched" not in kinds and "phone_gap" not in kinds, kinds
