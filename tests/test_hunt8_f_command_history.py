"""The command history's table in chromium, beside its tested path.

- An operator's slew the host deferred (the run suspended) and a newer target superseded before its slew
  started was said "superseded by a newer command before the board answered" — of a command never sent to
  the board; and while deferred, its acknowledgement was "—". Now each reads as what happened.
- The table was rebuilt whole on every status of every command, and held every command of the run: a long
  run's history (thousands of rows) was redrawn for each and grew without bound. Now it shows the newest
  ``SHOWN_MAX`` (the count says how many there are; the export has all) and a redraw touches only the rows
  that changed.

A real run's directory (its commands from the operator's schedule, the path a script's take), replayed by
``hil gcs``'s station.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from browser_support import chromium, js, page_errors, text
from fault_support import short_scenario
from gcs_support import wait_for

from hil.gcs import GroundStation
from hil.runtime import RunOptions, run
from hil.runtime.operator import OperatorCommand, ScheduledOperator

pytestmark = pytest.mark.browser

SHOWN_MAX = 300  # hil/gcs/static/commands.js
EXTRA = 5000  # commands appended to the run's own: a long run's history


@pytest.fixture(scope="module")
def browser():
    yield from chromium()


@pytest.fixture(scope="module")
def superseded_run(tmp_path_factory) -> Path:
    """A run disarmed at 5 s, a slew at 6 s (deferred), a hold at 6.5 s (superseding it), armed at 8 s."""
    schedule = [
        (5.0, OperatorCommand(1, "disarm", None, "test")),
        (6.0, OperatorCommand(2, "slew", (30.0, 0.0, 0.0), "test")),
        (6.5, OperatorCommand(3, "hold", None, "test")),
        (8.0, OperatorCommand(4, "arm", None, "test")),
    ]
    out = tmp_path_factory.mktemp("superseded")
    result = run(short_scenario(), RunOptions(out_root=out, observer=ScheduledOperator(schedule)))
    assert result.run_dir is not None
    return result.run_dir


def _replayed(browser, station: GroundStation) -> None:
    browser.get(station.url)
    wait_for(lambda: js(browser, "return window.gcs.state.status.state") == "finished", 30, "the replay")
    wait_for(lambda: "(" in text(browser, "cmd-history-count"), 10, "the command history")


def _move_to(browser, t: float) -> None:
    js(browser, """const s = document.getElementById('timeline'); s.value = arguments[0];
                   s.dispatchEvent(new Event('input'));""", t)  # fmt: skip


def _row(browser, ident: int) -> list[str]:
    row = """const tr = document.querySelector(`#cmd-history tbody tr[data-id="${arguments[0]}"]`);
             return tr ? Array.from(tr.cells, (c) => c.textContent) : null;"""
    return js(browser, row, str(ident))


def test_a_deferred_slew_superseded_by_a_newer_target_reads_right(browser, superseded_run) -> None:
    steps = [json.loads(line) for line in (superseded_run / "events.jsonl").read_text().splitlines()]
    slew = [e for e in steps if e["kind"] == "command" and e["id"] == 2]
    assert [e["status"] for e in slew] == ["deferred", "superseded"], slew  # the premise
    with GroundStation.replay(superseded_run, bind="127.0.0.1:0") as station:
        _replayed(browser, station)
        _move_to(browser, (slew[0]["t"] + slew[1]["t"]) / 2)  # deferred, not yet superseded
        wait_for(lambda: (_row(browser, 2) or [""] * 6)[4].startswith("deferred by the host"), 10, "deferred")
        row = _row(browser, 2)
        assert row[5] == "pending" and "suspended" in row[4], row
        _move_to(browser, slew[1]["t"] + 0.5)
        wait_for(lambda: "superseded" in (_row(browser, 2) or [""] * 6)[4], 10, "superseded")
        row = _row(browser, 2)
        assert "board" not in row[4], row  # never sent to the board: no board to answer
        assert row[4].startswith("superseded before its slew started"), row
    assert not page_errors(browser)


@pytest.fixture(scope="module")
def long_history(superseded_run, tmp_path_factory) -> tuple[Path, list[float]]:
    """The run's directory with ``EXTRA`` scripted commands (refused, each its own id) over its time."""
    run_dir = tmp_path_factory.mktemp("long") / superseded_run.name
    run_dir.mkdir()
    for f in superseded_run.iterdir():
        if f.is_file():
            (run_dir / f.name).write_bytes(f.read_bytes())
    own = [json.loads(line) for line in (run_dir / "events.jsonl").read_text().splitlines()]
    end = max(e["t"] for e in own)
    times = [round(end * (k + 1) / (EXTRA + 2), 6) for k in range(EXTRA)]
    with open(run_dir / "events.jsonl", "a") as f:
        for k, t in enumerate(times):
            record = {"t": t, "kind": "command", "origin": "script", "id": 1000 + k, "command": "hold",
                      "status": "refused", "reason": "drawn for the test"}  # fmt: skip
            f.write(json.dumps(record) + "\n")
    return run_dir, times


def test_a_long_history_is_bounded_and_redrawn_only_where_it_changed(browser, long_history) -> None:
    run_dir, times = long_history
    with GroundStation.replay(run_dir, bind="127.0.0.1:0") as station:
        _replayed(browser, station)
        wait_for(lambda: str(EXTRA + 4) in text(browser, "cmd-history-count"), 10, "every command counted")
        rows = js(browser, "return document.querySelectorAll('#cmd-history tbody tr').length")
        assert rows == SHOWN_MAX, rows  # bounded: the newest shown
        assert f"the newest {SHOWN_MAX} shown" in text(browser, "cmd-history-count")
        js(
            browser,
            "document.querySelectorAll('#cmd-history tbody tr').forEach((tr) => { tr.dataset.mark = '1'; })",
        )
        _move_to(browser, (times[-3] + times[-2]) / 2)  # two commands fewer: two older ones come in
        wait_for(lambda: str(1000 + EXTRA - 2) not in (_row(browser, 1000 + EXTRA - 2) or ["1"])[0], 10,
                 "the cursor moved back")  # fmt: skip
        marks = js(browser, """return Array.from(document.querySelectorAll('#cmd-history tbody tr'),
                                                 (tr) => tr.dataset.mark === '1');""")  # fmt: skip
        assert len(marks) == SHOWN_MAX and sum(marks) == SHOWN_MAX - 2, sum(marks)  # only the new rows drawn
        ids = js(
            browser,
            "return Array.from(document.querySelectorAll('#cmd-history tbody tr'), (tr) => tr.dataset.id)",
        )
        assert ids == [str(1000 + EXTRA - 3 - k) for k in range(SHOWN_MAX)], ids[:5]  # newest first, in order
    assert not page_errors(browser)
