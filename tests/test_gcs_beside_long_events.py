"""A run directory whose ``events.jsonl`` is longer than one read (``READ_CHUNK``, 4 MiB): every record is
shown before the reading stops.

Before, :meth:`RunDirSource.poll` read at most ``READ_CHUNK`` of each file per poll, and stopped
(``finished``, or ``read`` without following) as soon as the *telemetry* was read to its end: the events
past the first 4 MiB of a run that wrote more (a long run's commands, refusals, phone records; ~40 000
records) were never read, the line cut at the read's end counted as torn, and the page said "finished" —
lost without a word. Now the reading stops only when
both files are read to their end.

Through the real pieces: a real run's directory (``hil.runtime.run``) whose ``events.jsonl`` is made longer
than two reads, ``hil gcs``'s station on it, its ``/api/stream``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import pytest
from gcs_support import quick_scenario, read_stream

from hil.gcs import GroundStation
from hil.gcs.rundir import READ_CHUNK
from hil.runtime import RunOptions, run


@pytest.fixture(scope="module")
def long_run(tmp_path_factory) -> tuple[Path, int]:
    """A real run's directory, its events log made longer than two reads; and how many records it holds."""
    out = tmp_path_factory.mktemp("long-events")
    result = run(quick_scenario(), RunOptions(out_root=out, duration_s=2.0))
    path = result.run_dir / "events.jsonl"
    own = path.read_text().splitlines()
    end = json.loads(own[-1])["t"]
    extra, size, k = [], sum(len(line) + 1 for line in own), 0
    while size < 2.5 * READ_CHUNK:
        line = json.dumps({"t": end, "kind": "note", "k": k, "pad": "x" * 200})
        extra.append(line)
        size += len(line) + 1
        k += 1
    path.write_text("\n".join(own + extra) + "\n")
    return result.run_dir, len(own) + len(extra)


@pytest.mark.parametrize("follow", [True, False])
def test_every_record_of_a_long_events_log_is_sent_before_the_reading_stops(long_run, follow):
    """``hil gcs`` (following, and ``--no-follow``) on the run: the stream carries every record of its
    ``events.jsonl``, none counted as damaged, and ``finished`` comes after the last."""
    run_dir, records = long_run
    with GroundStation.replay(run_dir, bind="127.0.0.1:0", follow=follow) as station:
        end = "finished"  # the run has its summary: finished, followed or not

        def ended(messages: list[tuple[str, Any]]) -> bool:
            return any(name == "status" and data.get("state") == end for name, data in messages)

        messages = read_stream(station, 30, ended)
        time.sleep(0.2)
        stats = station.stats()["run_dir"]
    sent = [e for name, data in messages if name == "events" for e in data]
    assert len(sent) == records and stats["events"] == records and stats["bad_events"] == 0, (
        len(sent),
        stats,
    )
    assert sent[-1]["kind"] == "note" and sent[-1]["k"] == sum(e["kind"] == "note" for e in sent) - 1
    states = [data["state"] for name, data in messages if name == "status" and "state" in data]
    last_events = max(i for i, (name, _) in enumerate(messages) if name == "events")
    first_end = next(
        i for i, (name, data) in enumerate(messages) if name == "status" and data.get("state") == end
    )
    assert first_end > last_events, states
