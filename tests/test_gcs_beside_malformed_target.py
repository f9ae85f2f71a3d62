"""A command's target in a run directory's ``events.jsonl`` that parses but is no rotation.

The page shows the target of the newest applied command (``target_r``, a rotation vector in rad) as roll,
pitch and yaw. It took any ``target_r`` as it came: two numbers, strings, a value JSON could not carry
(``1e400``, sent as null) or one whose length overflows each drew ``NaN°, NaN°, NaN°`` as if it were a
target. A malformed one now leaves the target unknown (``—``) from its command on — not the target before
it, which the command replaced — until a well-formed one; the page raises no error.

Through the real pieces: a real run's directory with command records spliced into its events in time
order, ``hil gcs``'s replay station, the page in chromium, its timeline moved to each record.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from browser_support import chromium, js, page_errors, text
from gcs_support import quick_scenario, wait_for

from hil import so3
from hil.gcs import GroundStation
from hil.runtime import RunOptions, run
from hil.runtime.runlog import read_telemetry

pytestmark = pytest.mark.browser

MALFORMED = (
    "[0.1, 0.2]",  # two numbers
    "[0.1, 0.2, 0.3, 0.4]",  # four
    '["0.1", 0.2, 0.3]',  # a string among them
    "[1e400, 0, 0]",  # beyond a float: inf here, null on the wire
    "1e400",  # the whole value so
    "[true, 0, 0]",
    "[[0.1, 0.2, 0.3]]",  # nested
    '{"x": 0.1, "y": 0.2, "z": 0.3}',
    '"0.1 0.2 0.3"',
    "null",
    "[1.7e308, 1.7e308, 0]",  # each finite, the length not
)
GOOD_DEG = [(20.0, -10.0, 120.0), (-35.0, 15.0, -60.0)]


def _shown(euler: tuple[float, float, float]) -> str:
    return ", ".join(f"{x:.1f}°" for x in euler)


@pytest.fixture(scope="module")
def browser():
    yield from chromium()


@pytest.fixture(scope="module")
def spliced_run(tmp_path_factory) -> tuple[Path, list[tuple[float, str | None]]]:
    """A real run's directory with, after its own records, a well-formed target and then each malformed
    one followed by a well-formed one: (the directory, [(t, the target cell expected from t on)])."""
    out = tmp_path_factory.mktemp("malformed-target")
    result = run(quick_scenario(), RunOptions(out_root=out, duration_s=4.0))
    tel = read_telemetry(result.run_dir / "telemetry.csv")
    t_first, t_last = float(tel["t"][1]), float(tel["t"][-2])
    steps = 1 + 2 * len(MALFORMED)
    times = np.linspace(t_first + 0.2, t_last - 0.2, steps)
    records: list[tuple[float, str]] = []
    expected: list[tuple[float, str | None]] = []
    for k, t in enumerate(times.tolist()):
        if k % 2 == 0:
            euler = GOOD_DEG[(k // 2) % 2]
            value = json.dumps(so3.log(so3.euler_zyx(*euler)).tolist())
            expected.append((t, _shown(euler)))
        else:
            value = MALFORMED[k // 2]
            expected.append((t, None))
        records.append(
            (t, f'{{"t": {t!r}, "kind": "command", "command": "slew", "status": "applied", '
                       f'"target_r": {value}, "slew_s": 1.0}}')
        )  # fmt: skip
    path = result.run_dir / "events.jsonl"
    own = [(json.loads(line)["t"], line) for line in path.read_text().splitlines()]
    lines = [line for _, line in sorted(own + records, key=lambda pair: pair[0])]
    path.write_text("\n".join(lines) + "\n")
    return result.run_dir, expected


def test_a_malformed_target_shows_unknown_never_nan_and_a_good_one_after_it_shows(browser, spliced_run):
    run_dir, expected = spliced_run
    with GroundStation.replay(run_dir, bind="127.0.0.1:0") as station:
        browser.get(station.url)
        wait_for(lambda: js(browser, "return window.gcs.state.status.state") == "finished", 20, "the replay")
        for t, shown in expected:
            at = t + 0.05  # inside the record's interval (0.3 s), past its row
            js(browser, """const s = document.getElementById('timeline'); s.value = arguments[0];
                           s.dispatchEvent(new Event('input'));""", at)  # fmt: skip
            # the slider moves by steps: the cursor near `at`, past the record's time
            wait_for(
                lambda at=at: abs(js(browser, "return window.gcs.state.cursor") - at) < 0.02,
                5,
                f"the cursor at {at:.2f} s (it shows {text(browser, 'cursor-time')})",
            )
            cell = text(browser, "target")
            assert "NaN" not in cell, (t, cell)
            assert cell == (shown if shown is not None else "—"), (t, cell)
    assert not page_errors(browser)
