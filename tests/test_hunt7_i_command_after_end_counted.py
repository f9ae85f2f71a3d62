"""Commands and acknowledgements that come after a live run's loop has ended: answered 409 ``ended`` — the
run's ``events.jsonl`` is closed, so nothing can log them — and, before, counted nowhere: ``/api/stats``'
``uplink`` counted those refused before the run's start (``no_run``) but not these, so a script hammering a
finished run left no trace at all. Now each is counted as ``ended``; the run's record is unchanged."""

from __future__ import annotations

from gcs_support import RunInThread, command, quick_scenario, request

from hil.gcs import GroundStation
from hil.runtime import RunOptions
from hil.runtime.runlog import read_events


def test_commands_after_the_runs_end_are_refused_and_counted(tmp_path) -> None:
    bodies = [
        ("/api/command", {"command": "disarm"}),
        ("/api/command", {"command": "slew", "roll_deg": 1e160, "pitch_deg": 0, "yaw_deg": 0}),
        ("/api/ack", {"alarm": "point_err_deg:high", "raised_t": 1.0}),
    ]
    with GroundStation.live(bind="127.0.0.1:0") as station:
        result = RunInThread(quick_scenario(), RunOptions(out_root=tmp_path, duration_s=1.0), station).join()
        before = read_events(result.run_dir / "events.jsonl")[0]
        answers = [request(station, "POST", path, body) for path, body in bodies[::2]]
        assert all(status == 409 and answer["reason"] == "ended" for status, answer in answers), answers
        status, answer = command(station, bodies[1][1])  # out of range too: the run's end is said first
        assert status == 409 and answer["reason"] == "ended", answer
        stats = request(station, "GET", f"/api/stats?token={station.token}")[1]
        assert stats["uplink"]["ended"] == 3 and stats["uplink"]["accepted"] == 0, stats["uplink"]
    assert read_events(result.run_dir / "events.jsonl")[0] == before
