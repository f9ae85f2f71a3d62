"""What the ground station's header says of a run that ended without completing, in chromium: a live run the
operator aborted from the page, then the same run directory replayed with ``hil gcs``. The feed badge said
"ended" (live) or "finished" (replay), grey, the same as for a run that completed — only the small note
said ``exit: aborted: …`` — so an aborted, lost, interrupted or operator-disarmed run read as finished at a
glance. Now the badge names the outcome ("ended: aborted", "finished: aborted") in red; a completed run's
badge is unchanged."""

from __future__ import annotations

import pytest
from browser_support import chromium, js, text
from gcs_support import RunInThread, command, quick_scenario, wait_for

from hil.gcs import GroundStation
from hil.runtime import RunOptions

pytestmark = pytest.mark.browser


@pytest.fixture(scope="module")
def browser():
    yield from chromium()


def _badge(browser) -> tuple[str, list[str]]:
    classes = js(browser, "return document.getElementById('feed').className").split()
    return text(browser, "feed"), classes


def test_an_aborted_run_is_not_shown_as_finished_live_nor_in_replay(browser, tmp_path) -> None:
    with GroundStation.live(bind="127.0.0.1:0") as station:
        browser.get(station.url)
        runner = RunInThread(
            quick_scenario(), RunOptions(out_root=tmp_path, duration_s=20.0, pace=2.0), station
        )
        wait_for(lambda: text(browser, "feed") == "receiving", 30, "the page receiving")
        status, answer = command(station, {"command": "abort"})
        assert status == 202, answer
        result = runner.join()
        assert str(result.summary["exit"]).startswith("aborted"), result.summary["exit"]
        wait_for(lambda: text(browser, "feed").startswith("ended"), 20, "the page saying the run ended")
        badge, classes = _badge(browser)
        assert "aborted" in badge and "bad" in classes, (badge, classes)
        assert "ended" in classes  # still an ended run: no commands (uplink panel)
        assert js(browser, "return document.querySelector('button[data-command=arm]').disabled")
    with GroundStation.replay(result.run_dir, bind="127.0.0.1:0") as station:
        browser.get(station.url)
        wait_for(lambda: js(browser, "return window.gcs.state.status.state") == "finished", 30, "the replay")
        wait_for(lambda: text(browser, "feed").startswith("finished"), 10, "the badge")
        badge, classes = _badge(browser)
        assert badge != "finished" and "aborted" in badge and "bad" in classes, (badge, classes)


@pytest.mark.parametrize(
    ("exit", "said"),
    [
        ("lost: the board (no telemetry for 0.5 s)", "lost"),
        ("interrupted: SIGTERM", "interrupted"),
        ("disarmed by the operator at t=3.000 s and not armed again", "disarmed by the operator"),
        ({"code": 3}, "code 3"),
        ("completed", None),
    ],
)
def test_a_replayed_run_says_how_it_ended_in_its_badge(browser, tmp_path_factory, exit, said) -> None:
    import json

    from hil.runtime import run

    out = tmp_path_factory.mktemp("outcome")
    result = run(quick_scenario(), RunOptions(out_root=out, duration_s=2.0))
    path = result.run_dir / "summary.json"
    path.write_text(json.dumps({**json.loads(path.read_text()), "exit": exit}))
    with GroundStation.replay(result.run_dir, bind="127.0.0.1:0") as station:
        browser.get(station.url)
        wait_for(lambda: js(browser, "return window.gcs.state.status.state") == "finished", 30, "the replay")
        wait_for(lambda: text(browser, "feed").startswith("finished"), 10, "the badge")
        badge, classes = _badge(browser)
        if said is None:
            assert badge == "finished" and "bad" not in classes, (badge, classes)
        else:
            assert said in badge and "bad" in classes, (badge, classes)
