"""A gyroscope written in deg/s with no unit in its header is read as rad/s (SI, the default): before,
with no word (the attitude off by ~111 deg median on the real export). Now the replay compares the angle
the gyroscope integrates with the angle gravity's direction turns over one-second windows of motion
(:mod:`hil.logs.gyro_units`) and warns — in the setup notes, the summary and the log — naming the file and
deg/s; it never refuses a log.

The threshold's procedure, repeated here over every recording in ``../shared/data``: none of them as
recorded reaches it, and each of them with its gyroscope in deg/s does.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math

import pytest
from test_logs_layouts_beside import REAL, REAL_FILES

from hil.cli import main
from hil.estimation.sensors import SensorKind, SensorStream
from hil.logs import read_log
from hil.logs.gyro_units import DEG_S_RATIO, gyro_turn_ratio
from hil.scenario.paths import SHARED_DATA

pytestmark = pytest.mark.skipif(not REAL.is_dir(), reason="the shared Sensor Logger export is not here")

RECORDINGS = sorted(
    [*(SHARED_DATA / "tyrex-nexus5").glob("*/"), *(SHARED_DATA / "broad").glob("*.mat"), REAL],
    key=str,
)


def deg_s(log):
    """``log`` with its gyroscope's values as a deg/s column read as rad/s would give them."""
    g = log.streams[SensorKind.GYR]
    streams = {**log.streams, SensorKind.GYR: SensorStream(SensorKind.GYR, g.t, g.xyz * (180.0 / math.pi))}
    return dataclasses.replace(log, streams=streams)


@pytest.mark.parametrize("path", RECORDINGS, ids=lambda p: p.name)
def test_no_shared_recording_reaches_the_threshold_and_each_in_deg_s_does(path):
    log = read_log(path)
    ratio, windows = gyro_turn_ratio(log)
    assert windows >= 5 and ratio < DEG_S_RATIO / 2, (ratio, windows)  # a factor of 2 to spare
    suspect, _ = gyro_turn_ratio(deg_s(log))
    assert suspect > DEG_S_RATIO * 2, suspect
    assert suspect == pytest.approx(ratio * 180 / math.pi, rel=1e-6)


def _export(folder, scale: float, unit: str = ""):
    folder.mkdir(parents=True)
    for name in REAL_FILES:
        lines = (REAL / name).read_text(encoding="utf-8").splitlines()
        if name == "Gyroscope.csv":
            head = lines[0].split(",")
            lines = [",".join(head[:2] + [f"{c}{unit}" for c in head[2:]])] + [
                ",".join(r[:2] + [repr(float(c) * scale) for c in r[2:]])
                for r in (line.split(",") for line in lines[1:])
            ]
        (folder / name).write_text("\n".join(lines) + "\n", encoding="utf-8")
    return folder


@pytest.mark.parametrize(
    ("scale", "unit", "warned"),
    [(180 / math.pi, "", True), (1.0, "", False), (180 / math.pi, " (deg/s)", False)],
    ids=["deg-s-no-unit", "rad-s", "deg-s-named"],
)
def test_the_replay_warns_of_a_gyroscope_in_deg_s_without_its_unit(
    tmp_path, caplog, capsys, scale, unit, warned
):
    log = _export(tmp_path / "export", scale, unit)
    out = tmp_path / "out"
    with caplog.at_level(logging.WARNING):
        assert main(["replay", str(log), "--out", str(out), "--no-plots"]) == 0  # never refused
    summary = json.loads((out / "summary.json").read_text())
    said = [line for line in summary["setup"] if "deg/s, not rad/s" in line]
    logged = [r.message for r in caplog.records if "deg/s, not rad/s" in r.message]
    if warned:
        assert len(said) == 1 and "Gyroscope.csv" in said[0] and str(log) in said[0], said
        assert logged and "Gyroscope.csv" in logged[0]
        assert "deg/s, not rad/s" in capsys.readouterr().out
    else:
        assert not said and not logged
