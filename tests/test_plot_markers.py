"""The run figures' markers (hil/plots/markers.py): which events become a vertical line, and the lines in the
PNGs ``plot_run`` saves for a real run with a hung board."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from gcs_support import quick_scenario
from matplotlib.image import imread

from hil.plots import markers
from hil.plots.markers import COLORS, COMMAND, FAULT, MANOEUVRE, Marker, run_markers
from hil.plots.run import plot_run
from hil.runtime import RunOptions, run
from hil.runtime.runlog import read_events


def test_each_command_is_marked_once_with_its_target_and_faults_by_name():
    events = [
        {"t": 0.1, "kind": "board_state", "old": "BOOT", "new": "DISARMED"},
        {"t": 3.7, "kind": "slew_start"},
        {"t": 5.0, "kind": "command", "origin": "gcs", "id": None, "command": None, "status": "rejected"},
        {"t": 6.0, "kind": "command", "origin": "gcs", "id": 1, "command": "slew", "status": "applied",
         "target_euler_deg": [20, -10, 120]},
        {"t": 7.0, "kind": "command", "origin": "gcs", "id": 2, "command": "disarm", "status": "sent"},
        {"t": 7.02, "kind": "command", "origin": "gcs", "id": 2, "command": "disarm", "status": "acked"},
        {"t": 7.5, "kind": "command", "origin": "campaign", "id": 2, "command": "hold", "status": "refused"},
        {"t": 8.0, "kind": "board_state", "old": "ARMED", "new": "FAILSAFE"},
        {"t": 8.5, "kind": "board_reset"},
        {"t": 9.0, "kind": "link_lost"},
        {"t": 9.5, "kind": "phone_other", "sender": "127.0.0.1:5000"},
        {"t": 10.0, "kind": "phone_switch", "sender": "127.0.0.1:5001", "previous": "127.0.0.1:4000"},
    ]  # fmt: skip
    assert run_markers(events) == [
        Marker(3.7, "slew start", MANOEUVRE),
        Marker(6.0, "slew to 20/-10/120° (gcs)", COMMAND),
        Marker(7.0, "disarm (gcs)", COMMAND),
        Marker(7.5, "hold (campaign) refused", COMMAND),
        Marker(8.0, "FAILSAFE", FAULT),
        Marker(8.5, "board reset", FAULT),
        Marker(9.0, "link lost", FAULT),
        Marker(10.0, "phone switched", FAULT),
    ]


def test_the_page_marks_the_faults_the_saved_figures_mark():
    """hil/gcs/static/markers.js keeps its own table of the fault kinds marked (the page draws its plots
    itself): the same kinds and labels as the saved figures'."""
    text = (Path(markers.__file__).parents[1] / "gcs" / "static" / "markers.js").read_text()
    table = re.search(r"const FAULT_KINDS = \{(.*?)\};", text)
    assert table is not None
    page = dict(re.findall(r'(\w+): "([^"]*)"', table.group(1)))
    assert page == markers.FAULT_KINDS


def _vertical_line(path, color: str) -> int:
    """The most pixels of ``color`` (#rrggbb) in one pixel column of the PNG, counting a pixel blended with
    the white background (a line between two pixel columns is drawn half in each) as long as it is at least
    30 % the colour: a vertical line makes a tall column of them, text or a curve does not."""
    image = imread(path)[..., :3]
    rgb = np.array([int(color[i : i + 2], 16) for i in (1, 3, 5)]) / 255.0
    cover = np.clip(((1.0 - image) / (1.0 - rgb)).mean(axis=-1), 0.0, 1.0)  # how much of the colour
    blend = 1.0 - cover[..., None] * (1.0 - rgb)  # that much of it on white
    match = (cover > 0.3) & np.all(np.abs(image - blend) < 0.06, axis=-1)
    return int(match.sum(axis=0).max())


def test_the_saved_figures_mark_the_slew_and_the_faults(tmp_path):
    """A run whose board hangs at 4 s (a reset follows): pointing_error.png shows the slew's start and the
    fault in their colours; without the run's events the same figure has neither."""
    sc = quick_scenario().with_changes(fault_options={"hang_at": ["4.0"]})
    result = run(sc, RunOptions(out_root=tmp_path, duration_s=3.0))
    markers = run_markers(read_events(result.run_dir / "events.jsonl")[0])
    assert {m.kind for m in markers} == {MANOEUVRE, FAULT}
    assert any(m.label == "board reset" for m in markers)
    # the fault's red line (the manoeuvre's grey is too near the black axes' antialiased edges to tell
    # apart by colour: it is checked through the markers above)
    marked = _vertical_line(plot_run(result.run_dir)["pointing_error"], COLORS[FAULT])
    (result.run_dir / "events.jsonl").rename(result.run_dir / "events.hidden")
    bare = _vertical_line(plot_run(result.run_dir)["pointing_error"], COLORS[FAULT])
    assert marked > 150 and bare < 30, (marked, bare)  # a dashed line ~350 px tall; none
