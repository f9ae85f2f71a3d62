"""A live ground station kept open while the host plays a second run on it (``RunOptions.observer`` the same
station's): the page must be told the second run — its ``info``, its rows alone, commands taken again —
never the first run's description over the second run's rows, nor the first run's rows in its history."""

from __future__ import annotations

import json
import threading

from gcs_support import StreamReader, command, quick_scenario, read_stream, wait_for

from hil.gcs import GroundStation
from hil.runtime import RunOptions, run
from hil.runtime.runlog import read_events, read_telemetry


def _runs(station: GroundStation, tmp_path, n: int = 2) -> list:
    """``n`` short runs one after another, each observed by ``station``."""
    return [
        run(
            quick_scenario(),
            RunOptions(out_root=tmp_path / f"r{k}", duration_s=1.0, observer=station.observer),
        )
        for k in range(n)
    ]


def test_a_second_run_on_a_kept_station_is_described_and_its_history_is_its_own(tmp_path):
    with GroundStation.live(bind="127.0.0.1:0") as station:
        across = StreamReader(station, 60)  # a page open across both runs
        first, second = _runs(station, tmp_path)
        wait_for(lambda: sum(1 for e, _ in across.events() if e == "info") >= 2, 10, "the second run's info")
        infos = [d for e, d in across.events() if e == "info"]
        assert [i["run"] for i in infos] == [first.run_dir.name, second.run_dir.name]
        # a page that opens now: the second run, and only its rows (from its start, in time order)
        late = read_stream(station, 10, until=lambda m: any(e == "caught_up" for e, _ in m))
        across.close()
    assert [d["run"] for e, d in late if e == "info"] == [second.run_dir.name]
    rows = [r for e, d in late if e == "rows" for r in d["rows"]]
    tel = read_telemetry(second.run_dir / "telemetry.csv")
    assert len(rows) == tel.rows
    assert [r[0] for r in rows] == sorted(r[0] for r in rows)
    statuses = [d for e, d in late if e == "status"]
    assert statuses[-1]["state"] == "ended"


def test_the_second_run_takes_commands_again(tmp_path):
    """The first run's end sealed the uplink; the second run's start opens it again."""
    with GroundStation.live(bind="127.0.0.1:0") as station:
        run(quick_scenario(), RunOptions(out_root=tmp_path / "r0", duration_s=0.5, observer=station.observer))
        answers: list[tuple[int, object]] = []

        def send_when_started() -> None:
            wait_for(lambda: station.observer.started_at is not None
                     and station.observer.started_at.run_dir is not None
                     and "r1" in str(station.observer.started_at.run_dir), 30, "the second run")  # fmt: skip
            answers.append(command(station, {"command": "hold"}))

        sender = threading.Thread(target=send_when_started, daemon=True)
        sender.start()
        second = run(quick_scenario(), RunOptions(out_root=tmp_path / "r1", duration_s=3.0, pace=1.0,
                                                  observer=station.observer))  # fmt: skip
        sender.join(10)
    assert answers and answers[0][0] == 202, answers
    events = read_events(second.run_dir / "events.jsonl")[0]
    assert any(e.get("kind") == "command" and e.get("origin") == "gcs" for e in events), json.dumps(events)[
        :2000
    ]
