"""A command's target in a run directory's ``events.jsonl`` that parses but is no target.

The page shows the target of the newest applied command (``target_r``, a rotation vector in rad) as roll,
pitch and yaw, and each command's ``target_euler_deg`` in the command history and on the plots' markers.
It took any value as it came: two numbers, strings, a value JSON could not carry (``1e400``, sent as null)
or a rotation vector whose length overflows drew ``NaN°`` or ``undefined°``, and ``[0.1, 0.2]`` an identity
target as if it were real. A malformed ``target_r`` now leaves the target unknown (``—``) from its command
on — not the target before it, which the command replaced — until a well-formed one; a malformed
``target_euler_deg`` names the command without a target; the page raises no error.

Through the real pieces: a real run's directory with command records spliced into its events in time
order, ``hil gcs``'s replay station, the page in chromium, its timeline moved to each record.
"""

from __future__ import annotations

import json
import math
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


def _three_numbers(value: object) -> bool:
    """What the page takes as a target: three finite numbers (not bools)."""
    return (
        isinstance(value, list)
        and len(value) == 3
        and all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in value)
    )


def _shown(euler: tuple[float, float, float]) -> str:
    return ", ".join(f"{x:.1f}°" for x in euler)


@pytest.fixture(scope="module")
def browser():
    yield from chromium()


@pytest.fixture(scope="module")
def spliced_run(tmp_path_factory) -> tuple[Path, list[tuple[float, str | None]], list[str]]:
    """A real run's directory with, after its own records, a well-formed target and then each malformed
    one followed by a well-formed one: (the directory, [(t, the target cell expected from t on)], the
    records spliced in, in time order)."""
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
        euler_text = json.dumps(list(GOOD_DEG[(k // 2) % 2])) if k % 2 == 0 else value
        records.append(
            (t, f'{{"t": {t!r}, "kind": "command", "command": "slew", "status": "applied", "id": {k}, '
                f'"origin": "test", "target_r": {value}, "target_euler_deg": {euler_text}, "slew_s": 1.0}}')
        )  # fmt: skip
    path = result.run_dir / "events.jsonl"
    own = [(json.loads(line)["t"], line) for line in path.read_text().splitlines()]
    lines = [line for _, line in sorted(own + records, key=lambda pair: pair[0])]
    path.write_text("\n".join(lines) + "\n")
    return result.run_dir, expected, [line for _, line in records]


def test_a_malformed_target_shows_unknown_never_nan_and_a_good_one_after_it_shows(browser, spliced_run):
    run_dir, expected, records = spliced_run
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
        history = [
            row.split("\t")
            for row in js(
                browser,
                """return [...document.querySelectorAll('#cmd-history tbody tr')].map(
                     (tr) => [...tr.cells].map((td) => td.textContent).join('\\t'));""",
            )
        ]
        described = [cells[3] for cells in reversed(history)]  # newest first in the table
        markers = js(
            browser,
            """return import('/static/markers.js').then(
                 (m) => m.runMarkers(window.gcs.state.store.events).filter((x) => x.kind === 'command')
                         .map((x) => x.label));""",
        )
    assert len(described) == len(markers) == len(expected)
    for record, text_row, label in zip(records, described, markers, strict=True):
        assert "NaN" not in text_row + label and "undefined" not in text_row + label, (text_row, label)
        euler = json.loads(record)["target_euler_deg"]  # a malformed target_r's text stands for both
        if _three_numbers(euler):
            roll, pitch, yaw = euler
            assert text_row == f"slew to roll {roll:g}°, pitch {pitch:g}°, yaw {yaw:g}°"
            assert label == f"slew to {roll:g}/{pitch:g}/{yaw:g}° (test)"
        else:
            assert (text_row, label) == ("slew", "slew (test)")
    assert not page_errors(browser)
