"""A Sensor Logger export whose ``time`` is in ns since the phone booted (Android's sensor clock), not
since the epoch: it was read as an epoch in ms or µs (samples hours or seconds apart, or all NaN), as
phyphox seconds, or refused, by the size of its numbers alone. Built from the real export in
``../shared/data`` (read, never copied); it must read as the export itself, or end in one
:class:`InputFormatError` naming the file and column when it is truly ambiguous (docs/formats.md)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from log_support import REAL_T0_NS, assert_same_samples, needs_real_export, real_export

from hil.estimation.sensors import SensorKind
from hil.logs import detect_format, read_log
from protocol.errors import InputFormatError

SETTINGS = settings(
    max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)

pytestmark = needs_real_export


@pytest.fixture(scope="module")
def real_log(tmp_path_factory):
    return read_log(real_export(tmp_path_factory.mktemp("real") / "export"))


# --------------------------------------------------------------------------- 1. ns since boot
def boot_clock(uptime_ns: int, keep_elapsed: bool, header: str = "time"):
    """Every file's ``time`` moved onto a boot clock (ns since the phone started, ``uptime_ns`` at the
    recording's start), ``seconds_elapsed`` kept or left out."""

    def edit(name: str, lines: list[str]) -> list[str]:
        out = []
        for i, line in enumerate(lines):
            cells = line.split(",")
            cells[0] = header if i == 0 else str(int(cells[0]) - REAL_T0_NS + uptime_ns)
            if not keep_elapsed:
                del cells[1]
            out.append(",".join(cells))
        return out

    return edit


@SETTINGS
@given(
    uptime_ns=st.one_of(
        st.integers(10**10, 10**17),  # 10 s to 3 years since boot
        st.sampled_from([3_600 * 10**9, 12 * 86_400 * 10**9, 50 * 10**9]),  # ms-, µs-sized, and phyphox's
    ),
    keep_elapsed=st.booleans(),
)
def test_a_time_in_ns_since_boot_reads_as_the_export(tmp_path_factory, real_log, uptime_ns, keep_elapsed):
    """A ``time`` in ns since boot was read as an epoch in ms or µs (samples 20 000 s or 20 s apart, or
    every row a NaN sample), as phyphox seconds, or refused as no epoch — whatever its size said."""
    folder = real_export(tmp_path_factory.mktemp("boot") / "rec", boot_clock(uptime_ns, keep_elapsed))
    assert detect_format(folder) == "sensorlogger"
    log = read_log(folder)
    assert_same_samples(log, real_log)
    assert any("since the phone booted" in note for note in log.notes)


def test_a_time_in_ns_since_boot_with_its_unit_in_the_header_reads_as_the_export(tmp_path, real_log):
    folder = real_export(tmp_path / "rec", boot_clock(3_600 * 10**9, False, "time (ns)"))
    assert_same_samples(read_log(folder), real_log)


def test_a_time_that_is_ns_since_boot_or_us_since_the_epoch_alike_is_refused_naming_the_column(tmp_path):
    """1 kHz in ns since boot (12 days up) is 1 Hz in µs since the epoch (2002): no guess."""

    def edit(name: str, lines: list[str]) -> list[str]:
        rows = [line.split(",") for line in lines]
        out = [",".join([rows[0][0], *rows[0][2:]])]
        out += [",".join([str(12 * 86_400 * 10**9 + i * 10**6), *row[2:]]) for i, row in enumerate(rows[1:])]
        return out

    folder = real_export(tmp_path / "rec", edit)
    with pytest.raises(
        InputFormatError, match="since the phone booted.*since the epoch|since the epoch.*booted"
    ) as err:
        read_log(folder)
    assert err.value.column == "time"
    assert "Gyroscope.csv" in str(err.value)


def test_stray_rows_of_a_boot_clock_export_are_noted_on_its_clock_not_an_epoch(tmp_path, real_log):
    """A row at time 0 or at a negative time in an export on the boot clock is a NaN sample, dropped and
    counted, as in one on the epoch; its note once said "no epoch in ns since the phone booted"."""
    on_boot = boot_clock(3_600 * 10**9, True)

    def edit(name: str, lines: list[str]) -> list[str]:
        out = on_boot(name, lines)
        if name == "Gyroscope.csv":
            for row, time in ((5, "0"), (9, "-4000")):
                cells = out[row].split(",")
                cells[0] = time
                out[row] = ",".join(cells)
        return out

    log = read_log(real_export(tmp_path / "rec", edit))
    (note,) = [n for n in log.notes if "no time of this recording" in n]
    assert "Gyroscope.csv: 2 rows" in note and "ns since the phone booted" in note and "epoch" not in note
    gyr, real_gyr = log.streams[SensorKind.GYR], real_log.streams[SensorKind.GYR]
    assert np.isnan(gyr.xyz).any(axis=1).sum() - np.isnan(real_gyr.xyz).any(axis=1).sum() == 2
    assert_same_samples(log, real_log, [SensorKind.ACC, SensorKind.MAG])
