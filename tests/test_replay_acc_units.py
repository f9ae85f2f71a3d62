"""An accelerometer written in g with no unit in its header (Sensor Logger on iOS without "Standardise
Units & Frames", a script's re-export) was read as m/s² with no word. Now ``hil replay`` warns (setup
notes, summary, log) by the median norm (:mod:`hil.logs.acc_units`, whose threshold procedure is repeated
here over every shared recording); a unit the header states is converted."""

from __future__ import annotations

import dataclasses
import json
import logging

import numpy as np
import pytest
from hypothesis import HealthCheck, settings
from log_support import REAL_SENSORLOGGER, needs_real_export, real_export

from hil.cli import main
from hil.estimation.sensors import SensorKind, SensorStream
from hil.logs import read_log
from hil.logs.acc_units import G_NORM_M_S2, acc_norm_median, acc_unit_warning
from hil.scenario.paths import SHARED_DATA

SETTINGS = settings(
    max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)

pytestmark = needs_real_export


@pytest.fixture(scope="module")
def real_log(tmp_path_factory):
    return read_log(real_export(tmp_path_factory.mktemp("real") / "export"))


# --------------------------------------------------------------------------- 2. an accelerometer in g
RECORDINGS = sorted(
    [*(SHARED_DATA / "tyrex-nexus5").glob("*/"), *(SHARED_DATA / "broad").glob("*.mat"), REAL_SENSORLOGGER],
    key=str,
)


@pytest.mark.parametrize("path", RECORDINGS, ids=lambda p: p.name)
def test_no_shared_recording_is_below_the_g_bound_and_each_in_g_is(path):
    """The threshold's procedure (:mod:`hil.logs.acc_units`), repeated over every shared recording."""
    log = read_log(path)
    norm = acc_norm_median(log)
    assert norm > G_NORM_M_S2 * 2, norm  # a factor of 2 to spare
    acc = log.streams[SensorKind.ACC]
    in_g = dataclasses.replace(
        log, streams={**log.streams, SensorKind.ACC: SensorStream(SensorKind.ACC, acc.t, acc.xyz / 9.80665)}
    )
    assert acc_norm_median(in_g) < G_NORM_M_S2 / 2
    assert acc_unit_warning(log) is None and acc_unit_warning(in_g) is not None


def in_g(unit: str):
    """TotalAcceleration.csv's axes written in g, their header cells ending in ``unit``."""

    def edit(name: str, lines: list[str]) -> list[str]:
        if name != "TotalAcceleration.csv":
            return lines
        rows = [line.split(",") for line in lines]
        out = [",".join(rows[0][:2] + [f"{cell}{unit}" for cell in rows[0][2:]])]
        out += [",".join(row[:2] + [repr(float(c) / 9.80665) for c in row[2:]]) for row in rows[1:]]
        return out

    return edit


@pytest.mark.parametrize(("unit", "warned"), [("", True), (" (g)", False)], ids=["g-no-unit", "g-named"])
def test_the_replay_warns_of_an_accelerometer_in_g_without_its_unit(
    tmp_path, caplog, capsys, real_log, unit, warned
):
    """TotalAcceleration.csv in g with no unit was read as m/s² (a gravity of 1 m/s²) with no word."""
    folder = real_export(tmp_path / "export", in_g(unit))
    if unit:  # a unit the header states is converted
        acc = read_log(folder).streams[SensorKind.ACC]
        np.testing.assert_allclose(acc.xyz, real_log.streams[SensorKind.ACC].xyz, rtol=1e-12)
    out = tmp_path / "out"
    with caplog.at_level(logging.WARNING):
        assert main(["replay", str(folder), "--out", str(out), "--no-plots"]) == 0  # never refused
    summary = json.loads((out / "summary.json").read_text())
    said = [line for line in summary["setup"] if "in g, not m/s^2" in line]
    logged = [r.message for r in caplog.records if "in g, not m/s^2" in r.message]
    if warned:
        assert len(said) == 1 and "TotalAcceleration.csv" in said[0] and str(folder) in said[0], said
        assert logged and "in g, not m/s^2" in capsys.readouterr().out
    else:
        assert not said and not logged
