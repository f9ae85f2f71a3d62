"""``hil replay LOG --port URL`` of a log whose rate drops part-way says so, as the batch replay does
(:mod:`hil.logs.rates`): a phone that throttled its sensors half-way drove a board through the slow
stretch without a word (the drive builds its own warnings, apart from :func:`hil.logs.replay.replay`).
Through the real command against the in-process board in lockstep, on a CSV log in the project's format.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.cli import main

BOARD = "emu://?units=4&telemetry_rate=50"


def write_log(path: Path, fast_s: float, slow_hz: float, length_s: float) -> Path:
    """A still phone (gravity on z, a constant field, small noise) sampling at 100 Hz for ``fast_s``, then
    at ``slow_hz`` up to ``length_s`` (s): the project's CSV format."""
    rng = np.random.default_rng(3)
    times = np.concatenate([np.arange(0.0, fast_s, 0.01), np.arange(fast_s, length_s, 1.0 / slow_hz)])
    lines = ["# vscmg-hil sensor log v1", "t_s,sensor,x,y,z,w"]
    for t in times:
        g = rng.normal(0.0, 1e-3, 3)
        lines += [
            f"{t:.6f},gyr,{g[0]:.6f},{g[1]:.6f},{g[2]:.6f},",
            f"{t + 0.0002:.6f},acc,0.01,-0.01,9.81,",
            f"{t + 0.0004:.6f},mag,20.0,5.0,-40.0,",
        ]
    path.write_text("\n".join(lines) + "\n")
    return path


@settings(max_examples=3, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(fast_s=st.floats(4.0, 6.0), slow_hz=st.floats(8.0, 30.0))
def test_a_board_driven_through_a_rate_drop_is_told_of_it(tmp_path_factory, capsys, fast_s, slow_hz):
    capsys.readouterr()
    folder = tmp_path_factory.mktemp("drop")
    log = write_log(folder / "log.csv", fast_s, slow_hz, fast_s + 4.0)
    main(["replay", str(log), "--port", BOARD, "--out", str(folder / "out"), "--no-plots"])
    err = capsys.readouterr().err
    said = [line for line in err.splitlines() if "rate drops part-way" in line]
    assert {line.split("warning: ")[1].split(":")[0] for line in said} == {"gyr", "acc", "mag"}, err
    (run_dir,) = (folder / "out").iterdir()
    setup = json.loads((run_dir / "summary.json").read_text())["replay"]["setup"]
    assert sum("rate drops part-way" in line for line in setup) == 3, setup
