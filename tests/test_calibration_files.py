"""Bench CSVs and calibration files from real files: every malformed row, key or value is rejected with a
message naming the file and the line/column or key; calibration files round-trip exactly."""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_calibration_strategies import unit_calibrations

from hil.calibration.bench import BenchKind, read_bench_csv
from hil.calibration.files import (
    CalibrationSet,
    FitInfo,
    UnitEntry,
    dump_calibration,
    load_calibration,
    save_calibration,
)
from hil.scenario.paths import FIXTURES
from protocol.calibration import default_unit_calibration
from protocol.errors import CalibrationError, InputFormatError

GOOD_CSV = "# a bench run\npulse_us,battery_v,rpm,current_a\n1000,12.5,0,0.1\n\n1500, 12.3 ,3100,1.2\n"


# ------------------------------------------------------------------------- bench CSVs
def test_a_bench_csv_reads_into_si_units(tmp_path):
    path = tmp_path / "r.csv"
    path.write_text(GOOD_CSV)
    data = read_bench_csv(path)
    assert data.kind is BenchKind.ROTOR and data.column == "rpm" and len(data) == 2
    assert data.pulse_us.tolist() == [1000.0, 1500.0]
    assert data.battery_v.tolist() == [12.5, 12.3]
    assert data.value[1] == pytest.approx(3100 * 3.141592653589793 / 30)
    assert data.lines.tolist() == [3, 5]  # comment and blank lines counted
    assert data.where(1) == f"{path}:5"


@pytest.mark.parametrize(
    ("text", "line", "column", "phrase"),
    [
        ("", None, None, "no header line"),
        ("# only a comment\n\n", None, None, "no header line"),
        ("pulse_us,battery_v\n1000,12\n", 1, None, "exactly one measurement column"),
        ("pulse_us,battery_v,rpm,gimbal_rate_rad_s\n", 1, None, "found ['rpm', 'gimbal_rate_rad_s']"),
        ("pulse_us,rpm\n1000,0\n", 1, None, "needs a 'battery_v' column"),
        ("battery_v,rpm\n12,0\n", 1, None, "no 'pulse_us' column"),
        ("pulse_us,pulse_us,battery_v,rpm\n", 1, None, "duplicate column names ['pulse_us']"),
        ("pulse_us,battery_v,rpm\n# nothing measured\n", 1, None, "no data rows"),
        ("pulse_us,battery_v,rpm\n1000,12,0\n1100,12.1\n", 3, None, "2 fields, the header has 3"),
        ("pulse_us,battery_v,rpm\n1000,12,0\nabc,12,0\n", 3, "pulse_us", "'abc' is not a number"),
        ("pulse_us,battery_v,rpm\n1000,nan,0\n", 2, "battery_v", "not a finite number"),
        ("pulse_us,battery_v,rpm\n3000,12,0\n", 2, "pulse_us", "must be at least 500 and at most 2500"),
        ("pulse_us,battery_v,rpm\n1000,0,0\n", 2, "battery_v", "must be above 0 and at most 60"),
        ("pulse_us,battery_v,rpm\n1000,12,-5\n", 2, "rpm", "must be at least 0"),
        ("pulse_us,gimbal_rate_deg_s\n1000,inf\n", 2, "gimbal_rate_deg_s", "not a finite number"),
        ("pulse_us,gimbal_angle_rad\n1000,\n", 2, "gimbal_angle_rad", "'' is not a number"),
    ],
)
def test_malformed_bench_csvs_name_file_line_and_column(tmp_path, text, line, column, phrase):
    path = tmp_path / "bench.csv"
    path.write_text(text)
    with pytest.raises(InputFormatError) as info:
        read_bench_csv(path)
    err = info.value
    assert (err.path, err.line, err.column) == (str(path), line, column)
    assert phrase in str(err) and str(path) in str(err)


def test_unreadable_bench_files_are_named(tmp_path):
    with pytest.raises(InputFormatError, match="no such file") as info:
        read_bench_csv(tmp_path / "missing.csv")
    assert info.value.path.endswith("missing.csv")
    binary = tmp_path / "latin1.csv"
    binary.write_bytes(b"pulse_us,battery_v,rpm\n1000,12,0\xff\n")
    with pytest.raises(InputFormatError, match="not UTF-8"):
        read_bench_csv(binary)


# ------------------------------------------------------------------------- calibration files
names = st.text(st.characters(blacklist_categories=("Cs",)), max_size=20)
fits = st.builds(
    lambda source, points, largest, share, unit, battery: FitInfo(
        source, points, largest * share, largest, unit, battery
    ),
    st.text(max_size=30),
    st.integers(0, 10_000),
    st.floats(0, 1e3),
    st.floats(0, 1),  # a fit's rms residual is at most its largest
    st.sampled_from(["rad/s", "rad"]),
    st.none() | st.tuples(st.floats(1e-3, 60), st.floats(1e-3, 60)).map(lambda v: (min(v), max(v))),
)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    st.lists(
        st.tuples(
            unit_calibrations(),
            names,
            st.dictionaries(st.sampled_from(["rotor", "gimbal_rate", "gimbal_angle"]), fits),
        ),
        min_size=1,
        max_size=4,
    )
)
def test_calibration_files_round_trip_exactly(tmp_path, units):
    cset = CalibrationSet(tuple(UnitEntry(i, n, c, f) for i, (c, n, f) in enumerate(units)))
    path = save_calibration(cset, tmp_path / "set.toml")
    back = load_calibration(path)
    assert back == cset
    assert [u.calibration.to_bytes() for u in back.units] == [u.calibration.to_bytes() for u in cset.units]
    assert dump_calibration(back) == path.read_text()


def test_the_pyramid_fixture_loads_for_a_four_unit_board():
    cset = load_calibration(FIXTURES / "calibration" / "pyramid4.toml")
    assert [u.index for u in cset.units] == [0, 1, 2, 3]
    board_cals = cset.for_board(4)
    assert all(c is not None for c in board_cals)
    assert cset.for_board(5)[4] is None
    assert set(cset.unit(0).fits) == {"rotor", "gimbal_rate", "gimbal_angle"}
    assert (FIXTURES / "calibration" / cset.unit(0).fits["rotor"].source).exists()


def _good_text() -> str:
    entry = UnitEntry(
        0, "a", default_unit_calibration(), {"rotor": FitInfo("r.csv", 204, 1.5, 6.0, "rad/s", (10.4, 12.6))}
    )
    return dump_calibration(CalibrationSet((entry,)))


def _sub(old: str, new: str):
    def edit(text: str) -> str:
        assert old in text, old
        return text.replace(old, new, 1)

    return edit


@pytest.mark.parametrize(
    ("edit", "where", "phrase"),
    [
        (_sub("version = 1", "version = = 1"), "", "not valid TOML"),
        (_sub('format = "vscmg-hil calibration"', 'format = "other"'), "format", "is not"),
        (_sub("version = 1", "version = 2"), "version", "not supported"),
        (_sub("version = 1", "version = 1\nextra = 3"), "extra", "unknown key"),
        (lambda t: t.split("[[unit]]")[0], "unit", "missing"),
        (_sub("index = 0", "index = 9"), "unit[0].index", "not a unit number"),
        (lambda t: t + t[t.index("[[unit]]") :], "unit[1].index", "appears twice"),
        (_sub("low_us = 1000.0", "low = 1000.0"), "unit[0].esc.low", "unknown key"),
        (_sub("low_us = 1000.0", "low_us = 2100.0"), "unit[0].esc.low_us", "low_us < high_us"),
        (_sub("fraction = [0.0,", "fractions = [0.0,"), "unit[0].rotor.fractions", "unknown key"),
        (_sub("fraction = [0.0, ", "fraction = [0.0, 0.5, "), "unit[0].rotor.fraction", "11 throttle but 12"),
        (
            _sub("throttle = [0.0, 0.1,", "throttle = [0.0, 0.0,"),
            "unit[0].rotor.throttle",
            "increase strictly",
        ),
        (
            _sub("fraction = [0.0, 0.", "fraction = [0.0, -0."),
            "unit[0].rotor.fraction[1]",
            "not strictly monotone",
        ),
        (_sub("hold_us = 1500.0", 'hold_us = "1500"'), "unit[0].gimbal_rate.hold_us", "not a finite number"),
        (
            _sub("hold_us = 1500.0", "hold_us = 1600.0"),
            "unit[0].gimbal_rate.hold_us",
            "outside the dead zone",
        ),
        (
            _sub("angle_rad = [", "angle_rad = [true, "),
            "unit[0].gimbal_angle.angle_rad[0]",
            "not a finite number",
        ),
        (
            _sub("\npulse_us = [1000.0,", "\npulse_us = [1000.0, 1001.0,"),
            "unit[0].gimbal_angle.angle_rad",
            "10 pulse_us",
        ),
        (_sub("points = 204", "points = -1"), "unit[0].rotor.fit.points", "not a count"),
        (_sub("battery_v = [", "battery_v = [1.0, "), "unit[0].rotor.fit.battery_v", "array of 2 numbers"),
        # provenance that parses but no fit measured, once shown as measured (`hil calibrate show`, status 0)
        (_sub("rms_residual = 1.5", "rms_residual = -1.0"), "unit[0].rotor.fit.rms_residual", "no negative"),
        (
            _sub("max_residual = 6.0", "max_residual = 1.0"),
            "unit[0].rotor.fit.rms_residual",
            "above max_residual",
        ),
        (
            _sub("battery_v = [10.4, 12.6]", "battery_v = [12.6, 10.4]"),
            "unit[0].rotor.fit.battery_v",
            "no range",
        ),
        (
            _sub("battery_v = [10.4, 12.6]", "battery_v = [1e-300, 2500.0]"),
            "unit[0].rotor.fit.battery_v",
            "60 V",
        ),
        (_sub("[unit.gimbal_angle]", "[unit.gimbal_angles]"), "unit[0].gimbal_angles", "unknown key"),
    ],
)
def test_malformed_calibration_files_name_file_and_key(tmp_path, edit, where, phrase):
    path = tmp_path / "bad.toml"
    path.write_text(edit(_good_text()))
    with pytest.raises(CalibrationError) as info:
        load_calibration(path)
    err = str(info.value)
    assert err.startswith(f"{path}: ")
    assert where in info.value.where and phrase in err, err


def test_missing_calibration_file_is_named(tmp_path):
    with pytest.raises(CalibrationError, match="no such file"):
        load_calibration(tmp_path / "nope.toml")
