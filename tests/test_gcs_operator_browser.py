"""The ground station's operator tools in a real browser (headless chromium, tests/browser_support.py):
alarms raised, cleared and acknowledged as a lockstep run crosses a limit; commands and events marked on
the plots; the command history and a plot exported; keyboard scrubbing; light and dark; runs compared.

Each run here is lockstep (the simulated clock does not depend on the machine's load); every wait is on a
condition, with a generous deadline for a loaded 2-CPU machine.
"""

from __future__ import annotations

import numpy as np
import pytest
from browser_support import chromium, js, page_errors, text
from gcs_support import RunInThread, quick_scenario, wait_for

from hil.gcs import GroundStation
from hil.runtime import RunOptions
from hil.runtime.runlog import read_events, read_telemetry

pytestmark = pytest.mark.browser  # without chromium, chromedriver or selenium: skipped (tests/conftest.py)

try:
    from selenium.webdriver.common.by import By
except ImportError:  # then no test here runs: the marker skips them, with the one line for them all
    pass


@pytest.fixture(scope="module")
def browser():
    yield from chromium()


POINTING = "point_err_deg:high"


def _alarm_row(browser, key: str) -> dict | None:
    """The alarm list's row for ``key``, read in one script (the list is redrawn as the run goes on, so an
    element found in one call may be gone in the next): its classes, raised and cleared cells, ack cell."""
    return js(
        browser,
        """const tr = document.querySelector(`#alarms tr[data-key="${arguments[0]}"]`);
           if (!tr) return null;
           const cell = (c) => tr.querySelector('td.' + c).textContent;
           return {cls: tr.className, raised: tr.dataset.raised, cleared: cell('cleared'),
                   ack: cell('ack')};""",
        key,
    )


def test_an_alarm_is_raised_and_cleared_as_a_run_crosses_a_limit_and_acknowledged_from_the_page(
    browser, tmp_path
):
    """A pointing requirement of 15° (the scenario's ``settle_deg``): the 30° slew's pointing error is above
    it from the start and falls below it during the slew. The page lists the alarm (warning, raised at the
    first row past the limit), colours the pointing-error cell, sends the operator's acknowledgement (logged
    in events.jsonl with the occurrence's raised time), and marks the alarm cleared at the first row back
    inside the limit's hysteresis band — and raises no other."""
    sc = quick_scenario().with_changes(settle_deg=15.0)
    with GroundStation.live(bind="127.0.0.1:0") as station:
        browser.get(station.url)
        runner = RunInThread(sc, RunOptions(out_root=tmp_path, duration_s=5.0, pace=1.0), station)
        selector = f'#alarms tr[data-key="{POINTING}"]'
        row = wait_for(lambda: _alarm_row(browser, POINTING), 60, "the pointing alarm listed")
        assert "active" in row["cls"] and "warning" in row["cls"]
        assert text(browser, "alarm-badge") == "alarms: 1 active"
        wait_for(lambda: "alarm-warning" in (browser.find_element(By.ID, "point-err").get_attribute("class")),
                 10, "the pointing error cell coloured")  # fmt: skip
        raised = float(row["raised"])
        browser.save_screenshot(str(tmp_path / "alarm-raised.png"))
        js(browser, "document.querySelector(arguments[0] + ' button').click()", selector)
        ack = runner.wait_event(lambda e: e["kind"] == "alarm_ack", what="the acknowledgement logged")
        assert ack["alarm"] == POINTING and ack["origin"] == "gcs" and ack["remote"] == "127.0.0.1"
        assert ack["raised_t"] == pytest.approx(raised, abs=1e-6)
        wait_for(
            lambda: "✓" in _alarm_row(browser, POINTING)["ack"], 20, "the page to show the acknowledgement"
        )
        row = wait_for(lambda: (r := _alarm_row(browser, POINTING)) and "cleared" in r["cls"] and r, 60,
                       "the alarm cleared")  # fmt: skip
        cleared = float(row["cleared"])
        assert text(browser, "alarm-badge") == "alarms: none active"
        assert "alarm-warning" not in browser.find_element(By.ID, "point-err").get_attribute("class")
        browser.save_screenshot(str(tmp_path / "alarm-cleared.png"))
        result = runner.join()
        assert len(browser.find_elements(By.CSS_SELECTOR, "#alarms tbody tr[data-key]")) == 1
        limits = browser.find_element(By.ID, "plot-pointing").get_attribute("data-limits")
        assert "pointing error max=15" in limits  # the limit drawn on its plot
    assert not page_errors(browser)
    tel = read_telemetry(result.run_dir / "telemetry.csv")
    t, err = tel["t"], tel["point_err_deg"]
    first_out = int(np.nonzero(err > 15.0)[0][0])
    assert raised == pytest.approx(t[first_out], abs=1e-6)
    back = int(np.nonzero((t > raised) & (err <= 15.0 * 0.95))[0][0])
    assert cleared == pytest.approx(t[back], abs=0.006)  # the page shows two decimals
    assert np.all(err[back:] <= 15.0)  # and it stayed inside: one occurrence
    events = read_events(result.run_dir / "events.jsonl")[0]
    assert [e["alarm"] for e in events if e["kind"] == "alarm_ack"] == [POINTING]


def _click_twice(browser, name: str) -> None:
    """A command button's click and its confirmation, in one script (the page redraws between frames)."""
    script = "const b = document.querySelector(`button[data-command=${arguments[0]}]`); b.click(); b.click();"
    js(browser, script, name)


def _read_download(browser) -> tuple[str, bytes]:
    """The page's last export (#download): its file name and its bytes, read back through its Blob URL."""
    name, data = browser.execute_async_script("""
        const done = arguments[arguments.length - 1];
        const a = document.getElementById('download');
        fetch(a.href).then((r) => r.arrayBuffer())
          .then((b) => done([a.download, Array.from(new Uint8Array(b))]));
    """)  # fmt: skip
    return name, bytes(data)


def _export(browser, selector: str, before: str) -> tuple[str, bytes]:
    js(browser, "document.querySelector(arguments[0]).click()", selector)
    wait_for(lambda: browser.find_element(By.ID, "download").get_attribute("href") not in (None, "", before),
             20, "the export")  # fmt: skip
    return _read_download(browser)


def test_commands_are_marked_on_the_plots_listed_in_the_history_and_exported(browser, tmp_path):
    """A paced lockstep run: a slew commanded from the page is marked on the pointing plot at the time the
    run applied it; the history lists it, a Disarm (acked by the board) and a request with a wrong token
    (rejected) with sender, time, acknowledgement and outcome; its CSV export, read back through the Blob
    URL, says the same. A plot's CSV holds the points it shows, its PNG is a PNG; γ is in degrees in the
    plot as in the table; the events are a table that wraps rather than scrolls sideways."""
    import csv
    import io

    from gcs_support import command, request

    with GroundStation.live(bind="127.0.0.1:0") as station:
        browser.get(station.url)
        runner = RunInThread(
            quick_scenario(), RunOptions(out_root=tmp_path, duration_s=60.0, pace=2.0), station
        )
        runner.wait_event(lambda e: e["kind"] == "slew_start", 60, "the warm-up's end")
        wait_for(lambda: browser.find_element(By.CSS_SELECTOR, "button[data-command=slew]").is_enabled(), 20,
                 "the uplink on")  # fmt: skip
        js(browser, """for (const [k, v] of [['roll', 20], ['pitch', -10], ['yaw', 120]])
                         document.getElementById('slew-' + k).value = v;""")  # fmt: skip
        _click_twice(browser, "slew")
        applied = runner.wait_event(lambda e: e["kind"] == "command" and e.get("status") == "applied",
                                    what="the slew applied")  # fmt: skip
        pointing = browser.find_element(By.ID, "plot-pointing")
        label = f"{applied['t']} slew to 20/-10/120° (gcs)"
        wait_for(lambda: label in (pointing.get_attribute("data-markers") or "").split(";"), 20,
                 "the slew marked on the pointing plot")  # fmt: skip
        assert "slew start" in pointing.get_attribute("data-markers")
        browser.save_screenshot(str(tmp_path / "slew-marked.png"))
        _click_twice(browser, "disarm")
        runner.wait_event(
            lambda e: e["kind"] == "command" and e.get("status") == "acked", what="the disarm acked"
        )
        assert request(station, "POST", "/api/command", {"command": "hold"}, token="guessed")[0] == 401
        runner.wait_event(
            lambda e: e["kind"] == "command" and e.get("status") == "rejected", what="the rejection"
        )
        wait_for(lambda: len(browser.find_elements(By.CSS_SELECTOR, "#cmd-history tbody tr")) == 3, 20,
                 "three commands in the history")  # fmt: skip
        history = js(browser, """return Array.from(document.querySelectorAll('#cmd-history tbody tr'),
                                 (tr) => Array.from(tr.cells, (td) => td.textContent));""")  # fmt: skip
        _, csv_bytes = _export(browser, "#export-history", "")
        exported = list(csv.reader(io.StringIO(csv_bytes.decode())))

        href = browser.find_element(By.ID, "download").get_attribute("href")
        name, plot_csv = _export(browser, "#plot-pointing [data-export=csv]", href)
        href = browser.find_element(By.ID, "download").get_attribute("href")
        png_name, png = _export(browser, "#plot-pointing [data-export=png]", href)

        gimbal = browser.find_element(By.ID, "plot-gimbal_angle")
        assert "(°)" in gimbal.find_element(By.CSS_SELECTOR, "h3").text
        wait_for(lambda: abs(float(gimbal.get_attribute("data-last") or "nan")
                             - float(browser.find_element(By.ID, "u0-angle").text)) < 0.06, 10,
                 "γ in degrees in the plot as in the table")  # fmt: skip
        events_card = browser.find_element(By.CSS_SELECTOR, ".card.events")
        assert len(browser.find_elements(By.CSS_SELECTOR, "#events tbody tr")) > 5
        assert js(browser, "return arguments[0].scrollWidth <= arguments[0].clientWidth", events_card)
        command(station, {"command": "abort"})
        result = runner.join()
    assert not page_errors(browser)
    events = read_events(result.run_dir / "events.jsonl")[0]
    commands = [e for e in events if e["kind"] == "command"]
    slew = next(e for e in commands if e["command"] == "slew")
    disarm_sent = next(e for e in commands if e["command"] == "disarm" and e["status"] == "sent")
    disarm_acked = next(e for e in commands if e["command"] == "disarm" and e["status"] == "acked")
    rejected = next(e for e in commands if e["status"] == "rejected")
    assert (
        history[0][0] == ""
        and history[0][2] == "gcs 127.0.0.1"
        and history[0][5].startswith("rejected: token")
    )
    assert history[1][:3] == [str(disarm_sent["id"]), f"{disarm_sent['t']:.2f}", "gcs 127.0.0.1"]
    assert (
        history[1][4] == f"acked by the board after {disarm_acked['after_ms']:.0f} ms"
        and history[1][5] == "done"
    )
    assert history[2][:4] == [str(slew["id"]), f"{slew['t']:.2f}", "gcs 127.0.0.1",
                              "slew to roll 20°, pitch -10°, yaw 120°"]  # fmt: skip
    assert history[2][4:] == ["applied by the host", "done"]
    assert exported[0] == ["id", "t (s)", "sender", "command", "acknowledgement", "outcome"]
    assert [float(r[1]) for r in exported[1:]] == [slew["t"], disarm_sent["t"], rejected["t"]]
    assert [r[4] for r in exported[1:]] == [history[2][4], history[1][4], history[0][4]]
    assert name.endswith("-pointing.csv") and png_name.endswith("-pointing.png")
    rows = list(csv.reader(io.StringIO(plot_csv.decode())))
    assert rows[0] == ["t (s)", "pointing", "tracking"] and len(rows) > 20
    times = [float(r[0]) for r in rows[1:]]
    assert times == sorted(times) and times[-1] - times[0] <= 30.0  # the plot's window, as shown
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 2000


def _cursor(browser) -> float:
    return float(js(browser, "return window.gcs.state.cursor"))


def _at(browser, t: float) -> bool:
    """The page's cursor is at ``t`` (s; the downlink sends times to 10 significant digits)."""
    return abs(_cursor(browser) - t) < 1e-6


def test_the_keyboard_scrubs_the_timeline_and_the_colours_follow_the_system(browser, tmp_path):
    """A finished run replayed: → and ← move the cursor to the next and previous telemetry row, Shift+→ and
    Shift+← by one second, also with the timeline slider focused (whose own step is 0.01 s); Space plays
    and pauses; f follows the newest row again. A dark system scheme darkens the page, a light one not."""
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.keys import Keys

    from hil.runtime import run

    result = run(quick_scenario(), RunOptions(out_root=tmp_path, duration_s=4.0))
    t = read_telemetry(result.run_dir / "telemetry.csv")["t"]
    with GroundStation.replay(result.run_dir, bind="127.0.0.1:0") as station:
        browser.get(station.url)
        wait_for(lambda: js(browser, "return window.gcs.state.status.state") == "finished", 30, "the replay")
        wait_for(lambda: js(browser, "return window.gcs.state.store.n") == len(t), 20, "every row")
        keys = ActionChains(browser)

        def press(*sequence) -> None:
            for key in sequence:
                keys.send_keys(key)
            keys.perform()
            keys.reset_actions()

        js(browser, "document.activeElement.blur()")
        press(Keys.ARROW_LEFT)  # from following the last row: the row before it
        wait_for(lambda: _at(browser, t[-2]), 10, "one frame back")
        assert js(browser, "return window.gcs.state.follow") is False
        k = len(t) // 2
        js(browser, """const s = document.getElementById('timeline'); s.value = arguments[0];
                       s.dispatchEvent(new Event('input'));""", float(t[k]))  # fmt: skip
        wait_for(lambda: _at(browser, t[k]), 10, "the cursor at the middle row")
        press(Keys.ARROW_RIGHT)
        wait_for(lambda: _at(browser, t[k + 1]), 10, "one frame on")
        press(Keys.ARROW_LEFT, Keys.ARROW_LEFT)
        wait_for(lambda: _at(browser, t[k - 1]), 10, "two frames back")
        keys.key_down(Keys.SHIFT).send_keys(Keys.ARROW_RIGHT).key_up(Keys.SHIFT).perform()
        keys.reset_actions()
        wait_for(lambda: _at(browser, t[k - 1] + 1.0), 10, "a second on")
        keys.key_down(Keys.SHIFT).send_keys(Keys.ARROW_LEFT, Keys.ARROW_LEFT).key_up(Keys.SHIFT).perform()
        keys.reset_actions()
        wait_for(lambda: _at(browser, t[k - 1] - 1.0), 10, "two seconds back")
        assert text(browser, "cursor-time").startswith(f"{t[k - 1] - 1.0:.2f}")
        # the slider focused: its own arrow step (0.01 s) is not what happens
        js(browser, "document.getElementById('timeline').focus()")
        before = _cursor(browser)
        i = int(np.searchsorted(t, before, side="right")) - 1
        press(Keys.ARROW_RIGHT)
        wait_for(lambda: _at(browser, t[i + 1]), 10, "one frame on from the slider")
        # Space plays from the cursor and pauses
        js(browser, "document.activeElement.blur()")
        start = _cursor(browser)
        press(Keys.SPACE)
        wait_for(lambda: js(browser, "return window.gcs.state.playing"), 10, "playing")
        wait_for(lambda: _cursor(browser) > start + 0.2, 20, "the cursor to move on while playing")
        press(Keys.SPACE)
        wait_for(lambda: not js(browser, "return window.gcs.state.playing"), 10, "paused")
        paused = _cursor(browser)
        assert paused > start
        press("f")
        wait_for(lambda: js(browser, "return window.gcs.state.follow") and _at(browser, t[-1]), 10,
                 "following the newest row")  # fmt: skip

        def background() -> tuple[int, ...]:
            rgb = js(browser, "return getComputedStyle(document.body).backgroundColor")
            return tuple(int(x) for x in rgb[rgb.index("(") + 1 : rgb.index(")")].split(",")[:3])

        try:
            for scheme, dark in (("dark", True), ("light", False)):
                features = [{"name": "prefers-color-scheme", "value": scheme}]
                browser.execute_cdp_cmd("Emulation.setEmulatedMedia", {"features": features})
                wait_for(lambda d=dark: (sum(background()) < 150) == d, 10, f"the {scheme} scheme")
                browser.save_screenshot(str(tmp_path / f"{scheme}.png"))
        finally:
            browser.execute_cdp_cmd("Emulation.setEmulatedMedia", {"features": []})
    assert not page_errors(browser)


def test_two_runs_compared_on_one_page(browser, tmp_path):
    """Two real lockstep runs (a 30° and a 15° slew) compared: every row of each reaches the page, the
    pointing plot's legend names each run, and its points — exported as CSV — are each run's own values at
    the first run's times."""
    import csv
    import io

    from hil.runtime import run

    a = run(quick_scenario(30.0), RunOptions(out_root=tmp_path / "a", duration_s=3.0, label="wide")).run_dir
    b = run(quick_scenario(15.0), RunOptions(out_root=tmp_path / "b", duration_s=3.0, label="narrow")).run_dir
    tel_a, tel_b = read_telemetry(a / "telemetry.csv"), read_telemetry(b / "telemetry.csv")
    with GroundStation.compare([a, b], bind="127.0.0.1:0") as station:
        browser.get(station.url)
        first = "return window.gcs.state.store && window.gcs.state.store.n"
        second = "const o = window.gcs.state.overlays[1]; return o && o.store.n"
        wait_for(lambda: js(browser, first) == tel_a.rows, 30, "every row of the first run")
        wait_for(lambda: js(browser, second) == tel_b.rows, 30, "every row of the second run")
        assert text(browser, "mode") == "compare: 2 runs"
        assert a.name in text(browser, "run-name") and b.name in text(browser, "run-name")
        legend = [e.text for e in browser.find_elements(By.CSS_SELECTOR, "#plot-pointing .u-legend .u-label")]
        assert f"pointing · {a.name}" in legend and f"pointing · {b.name}" in legend
        _js_select_window_all(browser)
        name, data = _export(browser, "#plot-pointing [data-export=csv]", "")
        browser.save_screenshot(str(tmp_path / "compare.png"))
    assert not page_errors(browser)
    rows = list(csv.reader(io.StringIO(data.decode())))
    header = rows[0]
    assert header == ["t (s)", f"pointing · {a.name}", f"tracking · {a.name}", f"pointing · {b.name}",
                      f"tracking · {b.name}"]  # fmt: skip
    points = np.array([[float(x) if x else np.nan for x in r] for r in rows[1:]])
    assert len(points) == tel_a.rows  # the whole first run (window "all"; under the page's point cap)
    for col, tel in ((1, tel_a), (3, tel_b)):
        i = np.searchsorted(tel["t"], points[:, 0] + 1e-9, side="right") - 1  # each run's row at that time
        np.testing.assert_allclose(points[:, col], tel["point_err_deg"][i], rtol=1e-6, atol=1e-9)
    assert np.nanmax(np.abs(points[:, 1] - points[:, 3])) > 10.0  # the two runs differ, each drawn


def _js_select_window_all(browser) -> None:
    js(browser, """const w = document.getElementById('window'); w.value = '0';
                   w.dispatchEvent(new Event('change'));""")  # fmt: skip
    shown = "return document.getElementById('plot-pointing').dataset.points"
    rows = "return window.gcs.state.store.n"
    wait_for(lambda: js(browser, shown) == str(js(browser, rows)), 10, "the whole run in the plot")
