"""Fitting maps to bench data whose truth is known (generated from the stated models with noise), and the
validation that refuses data which cannot make a sane monotone map, naming file and rows."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from hil.calibration.bench import parse_bench_csv, read_bench_csv
from hil.calibration.fit import FitOptions, fit_bench
from hil.calibration.generate import bench_units, generate_bench
from protocol.calibration import GimbalRateMap, RotorSpeedMap
from protocol.errors import CalibrationError, InputFormatError

SEED = 11


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    """Bench CSVs of two units (unit 1's gimbal mounted mirrored) and their true models."""
    out = tmp_path_factory.mktemp("bench")
    generate_bench(out, n_units=2, seed=SEED, mirrored=(1,))
    return out, bench_units(2, SEED, mirrored=(1,))


@pytest.mark.parametrize("unit", [0, 1])
def test_fits_recover_the_true_models(bench, unit):
    out, truth = bench
    motor, gimbal = truth[unit].motor, truth[unit].gimbal
    rotor = fit_bench(read_bench_csv(out / f"unit{unit}_rotor.csv"))
    assert isinstance(rotor.map, RotorSpeedMap)
    assert rotor.map.kv_rad_s_per_v == pytest.approx(motor.kv_rad_s_per_v, rel=0.01)
    assert rotor.map.esc.deadband_us == pytest.approx(motor.deadband_us, abs=3.0)
    for v in (10.5, 12.6):
        err = max(abs(rotor.map.speed(p, v).value - motor.speed(p, v)) for p in range(1000, 2001, 5))
        assert err < 0.01 * motor.kv_rad_s_per_v * v  # within 1 % of full speed everywhere
    assert rotor.report.rms < 3.0  # rad/s: the tachometer noise (0.5 % + 1 rad/s), not model error
    assert rotor.report.battery_v is not None and rotor.report.battery_v[1] - rotor.report.battery_v[0] > 1.5

    rate = fit_bench(read_bench_csv(out / f"unit{unit}_gimbal_rate.csv"))
    assert isinstance(rate.map, GimbalRateMap)
    lo, hi = rate.map.dead_zone_us
    true_lo, true_hi = gimbal.center_us - gimbal.deadband_us, gimbal.center_us + gimbal.deadband_us
    assert lo == pytest.approx(true_lo, abs=5.0)  # within half a sweep step
    assert hi == pytest.approx(true_hi, abs=5.0)
    assert true_lo <= rate.map.hold_us <= true_hi  # the hold pulse really holds the true servo still
    err = max(
        abs(rate.map.rate(p).value - gimbal.rate(p))
        for p in range(1000, 2001, 5)
        if abs(p - gimbal.center_us) > 20
    )
    assert err < 0.03  # rad/s, against 0.01 rad/s gyro noise
    assert rate.report.rms < 0.015
    assert rate.map.upper.rising == (gimbal.direction > 0)

    angle = fit_bench(read_bench_csv(out / f"unit{unit}_gimbal_angle.csv"))
    errors = [
        (abs(p - gimbal.center_us), abs(angle.map.angle(p).value - gimbal.angle(p)))
        for p in range(1000, 2001, 5)
    ]
    # rad, against 0.003 rad encoder noise; near the sweep's ends the true servo reaches its mechanical stop
    # (a flat end no strictly monotone map follows exactly)
    assert max(e for off, e in errors if off <= gimbal.half_span_us - 10) < 0.006
    assert max(e for _, e in errors) < 0.02
    assert angle.report.rms < 0.005


def test_fit_options_are_honoured(bench):
    out, truth = bench
    fit = fit_bench(read_bench_csv(out / "unit0_rotor.csv"), FitOptions(rotor_knots=5))
    assert len(fit.map.curve.x) == 5 and fit.report.knots == 5
    fit = fit_bench(read_bench_csv(out / "unit0_gimbal_rate.csv"), FitOptions(gimbal_rate_knots_per_side=4))
    assert len(fit.map.lower.x) == len(fit.map.upper.x) == 4
    with pytest.raises(CalibrationError, match="FitOptions.rotor_knots"):
        FitOptions(rotor_knots=17)
    with pytest.raises(CalibrationError, match="FitOptions"):
        FitOptions(esc_low_us=2000.0, esc_high_us=1000.0)


# ------------------------------------------------------------------------- validation
def _edited(out, name: str, keep=lambda p, v, w: True, change=lambda p, v, w: (p, v, w)) -> str:
    """The CSV ``name`` with rows filtered by ``keep`` and rewritten by ``change`` (numbers as floats)."""
    lines = (out / name).read_text().splitlines()
    head = [ln for ln in lines if ln.startswith("#") or not ln[0].isdigit()]
    rows = []
    for ln in lines[len(head) :]:
        p, v, w = (float(c) for c in ln.split(","))
        if keep(p, v, w):
            rows.append(",".join(f"{x:g}" for x in change(p, v, w)))
    return "\n".join(head + rows) + "\n"


def _fit_text(text: str, path: str, **options):
    return fit_bench(parse_bench_csv(text, path), FitOptions(**options))


def _lines_named(message: str) -> set[int]:
    m = re.search(r"lines? ([\d, ]+)", message)
    assert m, message
    return {int(n) for n in m.group(1).replace(" ", "").split(",") if n}


def test_data_that_is_not_monotone_is_refused_naming_its_rows(bench):
    out, _ = bench
    text = _edited(out, "unit0_rotor.csv", change=lambda p, v, w: (p, v, 500.0 if p == 1600 else w))
    with pytest.raises(CalibrationError) as info:
        _fit_text(text, "bench/r.csv")
    msg = str(info.value)
    assert msg.startswith("bench/r.csv: ") and "not monotone in pulse" in msg
    want = {i + 1 for i, ln in enumerate(text.splitlines()) if ln.startswith("1600,")}
    named = _lines_named(msg)
    assert want <= named  # every bad row (the fit bends towards them, so neighbours may be named too)
    assert all(min(abs(n - w) for w in want) <= 2 for n in named)


def test_a_single_outlier_row_is_named(bench):
    out, _ = bench
    text = _edited(out, "unit0_gimbal_angle.csv", change=lambda p, v, w: (p, v, 9.0 if p == 1500 else w))
    line = next(i + 1 for i, ln in enumerate(text.splitlines()) if ln.startswith("1500,"))
    with pytest.raises(CalibrationError, match=rf"bench/a.csv: line {line} lie"):
        _fit_text(text, "bench/a.csv")


@pytest.mark.parametrize(
    ("name", "keep", "change", "options", "phrase"),
    [
        ("unit0_rotor.csv", lambda p, v, w: not 1250 < p < 1550, None, {}, "no samples between throttle"),
        ("unit0_rotor.csv", lambda p, v, w: 1200 <= p <= 1800, None, {}, "do not cover the ESC endpoints"),
        ("unit0_rotor.csv", lambda p, v, w: p % 400 == 0, None, {}, "this fit needs at least"),
        ("unit0_rotor.csv", None, lambda p, v, w: (p, v, 0.0), {}, "never turned"),
        ("unit0_rotor.csv", None, None, {"esc_low_us": 1100.0}, "turns at or below the low endpoint 1100"),
        ("unit0_rotor.csv", None, lambda p, v, w: (p, v, w if p >= 1400 else 0), {}, "deadband over 30 %"),
        ("unit0_gimbal_rate.csv", lambda p, v, w: p >= 1600, None, {}, "need 3+ each way"),
        ("unit0_gimbal_rate.csv", lambda p, v, w: not 1600 < p < 1800, None, {}, "no samples between pulse"),
        (
            "unit0_gimbal_rate.csv",
            lambda p, v, w: 1400 <= p <= 1590,
            None,
            {"gimbal_rate_knots_per_side": 3},
            "only span 190",
        ),
        ("unit0_gimbal_angle.csv", None, lambda p, v, w: (p, v, 0.25), {}, "the angle never changes"),
    ],
)
def test_unfit_data_is_refused_naming_the_file(bench, name, keep, change, options, phrase):
    out, _ = bench
    text = _edited(out, name, keep or (lambda p, v, w: True), change or (lambda p, v, w: (p, v, w)))
    with pytest.raises(CalibrationError) as info:
        _fit_text(text, f"bench/{name}", **options)
    assert str(info.value).startswith(f"bench/{name}: ") and phrase in str(info.value), str(info.value)


def test_rotor_speeds_in_rpm_and_rad_s_fit_the_same(bench):
    out, _ = bench
    text = (out / "unit0_rotor.csv").read_text()
    rad = "\n".join(
        ln
        if not ln[:1].isdigit()
        else ",".join([*ln.split(",")[:2], repr(float(ln.split(",")[2]) * math.pi / 30)])
        for ln in text.replace("battery_v,rpm", "battery_v,rotor_speed_rad_s").splitlines()
    )
    a = fit_bench(parse_bench_csv(text, "rpm.csv")).map
    b = fit_bench(parse_bench_csv(rad, "rad.csv")).map
    grid = np.arange(1000, 2001, 50)
    np.testing.assert_allclose(
        [a.speed(p, 11.1).value for p in grid], [b.speed(p, 11.1).value for p in grid], atol=1e-3
    )


BENCH = Path(__file__).resolve().parents[1] / "fixtures" / "calibration" / "bench"


def _scaled(name: str, scale: float) -> str:
    """A bench CSV of the fixtures with its measurement column (the last) multiplied by ``scale``."""
    out = []
    for line in (BENCH / name).read_text().splitlines():
        cells = line.split(",")
        if line.startswith("#") or not cells[-1].lstrip("-")[:1].isdigit():
            out.append(line)
        else:
            out.append(",".join([*cells[:-1], repr(float(cells[-1]) * scale)]))
    return "\n".join(out) + "\n"


@pytest.mark.parametrize("name", ["unit0_rotor.csv", "unit0_gimbal_rate.csv", "unit0_gimbal_angle.csv"])
def test_a_measurement_no_bench_makes_is_refused_naming_its_line_and_column(name):
    """A rate of 1e160 parses but was never measured: refused as the file is read (it reached the fit,
    and scipy's ValueError ended `hil calibrate fit` with a traceback)."""
    text = _scaled(name, 1e160)
    with pytest.raises(InputFormatError) as err:
        parse_bench_csv(text, name)
    column = text.splitlines()[3].split(",")[-1]
    assert err.value.column == column and err.value.line is not None and name in str(err.value)


@pytest.mark.parametrize(
    ("name", "said"),
    [("unit0_rotor.csv", "rotor never turned"), ("unit0_gimbal_rate.csv", "gimbal never turned"),
     ("unit0_gimbal_angle.csv", "angle never changes")],
)  # fmt: skip
def test_a_sweep_in_which_nothing_moved_is_refused_not_fitted(name, said):
    """Every value 1e-300 of itself: the shape of a sweep, but nothing moved. The fits' tests are relative
    to the sweep's top, so such a sweep got a map (a gimbal rate range of ±5e-10 rad/s)."""
    with pytest.raises(CalibrationError, match=said):
        fit_bench(parse_bench_csv(_scaled(name, 1e-300), name))
