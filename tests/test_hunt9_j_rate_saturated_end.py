"""A gimbal-rate sweep whose rate stops growing at one end — a continuous servo at its top rate, which it
reaches by design — must be fitted over the part that grows only, and said so by ``hil calibrate fit``.

An angle sweep with a flat end was refused naming the end; a rate sweep's flat end was fitted as if the rate
grew: the table rose over the plateau by its minimum increments (1e-4 of the top rate per knot interval),
the command printed nothing about it, and a rate near the top was commanded anywhere on the plateau (a
rate the servo reached a hundred µs sooner put at the end of the sweep). Now the saturated rows are left
out of the fit, named in a note of the fit's summary, and the table ends where the rate reached its top.

The data is the committed bench's, its rate held beyond a drawn pulse; the command is the real one (in
process), its files real.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.calibration.files import load_calibration
from hil.cli import main

BENCH = Path(__file__).resolve().parents[1] / "fixtures" / "calibration" / "bench"


def _saturated(source: Path, out: Path, end: str, at_us: int) -> float:
    """``source`` with every rate beyond the one measured at ``at_us`` (towards ``end``) held at it, plus
    the sweep's own noise (the rows' differences to the row at ``at_us``'s neighbours are kept). Returns
    the held rate (rad/s)."""
    lines = source.read_text().splitlines()
    rows = [line.split(",") for line in lines if line[:1].isdigit()]
    held = next(float(r) for p, _, r in rows if int(p) == at_us)
    out_lines = []
    for k, line in enumerate(lines):
        if line[:1].isdigit():
            p, v, r = line.split(",")
            beyond = int(p) > at_us if end == "high" else int(p) < at_us
            noise = 0.01 * ((k * 7919) % 3 - 1)  # rad/s: -0.01, 0 or 0.01, as a gyro's reading
            line = f"{p},{v},{held + noise if beyond else float(r):.4f}"
        out_lines.append(line)
    out.write_text("\n".join(out_lines) + "\n")
    return held


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    unit=st.sampled_from([0, 3]),  # unit 3's servo is mounted mirrored: its rate falls with the pulse
    end=st.sampled_from(["low", "high"]),
    plateau_us=st.integers(min_value=8, max_value=25).map(lambda k: 10 * k),  # 80..250 µs of plateau
)
def test_a_saturated_end_of_a_rate_sweep_is_left_out_and_said(capsys, unit, end, plateau_us):
    source = BENCH / f"unit{unit}_gimbal_rate.csv"
    pulses = [int(line.split(",")[0]) for line in source.read_text().splitlines() if line[:1].isdigit()]
    at_us = max(pulses) - plateau_us if end == "high" else min(pulses) + plateau_us
    with tempfile.TemporaryDirectory() as tmp:
        csv, out = Path(tmp) / "rate.csv", Path(tmp) / "cal.toml"
        held = _saturated(source, csv, end, at_us)
        code = main(["calibrate", "fit", str(csv), "-o", str(out), "--base", "default"])
        said = capsys.readouterr()
        assert code == 0, said.err
        assert f"the servo saturates at the {end} end" in said.out, said.out
        entry = load_calibration(out).unit(0)
        assert entry is not None
        rate_map = entry.calibration.gimbal_rate
    table = rate_map.upper if end == "high" else rate_map.lower
    table_end = table.x[-1] if end == "high" else table.x[0]
    # the table ends where the rate reached its top (within two sweep steps), not at the sweep's end
    assert abs(table_end - at_us) <= 20.0, (table_end, at_us)
    # a rate just short of the top is commanded before the plateau, not on it
    pulse = rate_map.pulse(0.98 * held).value
    assert (pulse <= at_us + 10.0) if end == "high" else (pulse >= at_us - 10.0), (pulse, at_us)


def test_the_committed_rate_sweeps_fit_with_nothing_left_out(tmp_path, capsys):
    for unit in range(4):
        out = tmp_path / f"cal{unit}.toml"
        csv = BENCH / f"unit{unit}_gimbal_rate.csv"
        code = main(["calibrate", "fit", str(csv), "-o", str(out), "--base", "default"])
        said = capsys.readouterr()
        assert code == 0, said.err
        assert "note:" not in said.out, said.out


def test_an_emulated_sweep_past_the_servos_travel_fits_up_to_where_it_saturates(tmp_path):
    """The emulated bench's continuous servo reaches its top rate ±500 µs from its centre (1500 µs): a
    real ``hil calibrate sweep`` from 800 to 2200 µs, then ``hil calibrate fit``, each a subprocess of the
    CLI. Before, the table ran to 800 and 2200 µs, bent over the plateaus (residuals 0.013 rad/s rms on a
    noiseless sweep), and 1.999 rad/s was commanded at 2036 µs; now it ends where the rate reached its top."""
    import subprocess
    import sys

    hil = [sys.executable, "-m", "hil"]
    sweep = subprocess.run(
        [*hil, "calibrate", "sweep", "--port", "emu://", "--unit", "0", "--map", "gimbal_rate",
         "--out-dir", str(tmp_path), "--range", "800:2200", "--step", "40"],
        capture_output=True, text=True, timeout=240,
    )  # fmt: skip
    assert sweep.returncode == 0, sweep.stderr
    csv, out = tmp_path / "unit0_gimbal_rate.csv", tmp_path / "cal.toml"
    fit = subprocess.run(
        [*hil, "calibrate", "fit", str(csv), "-o", str(out), "--base", "default"],
        capture_output=True, text=True, timeout=240,
    )  # fmt: skip
    assert fit.returncode == 0, fit.stderr
    assert "saturates at the low end" in fit.stdout and "saturates at the high end" in fit.stdout, fit.stdout
    entry = load_calibration(out).unit(0)
    assert entry is not None
    rate_map = entry.calibration.gimbal_rate
    assert abs(rate_map.lower.x[0] - 1000.0) <= 40.0 and abs(rate_map.upper.x[-1] - 2000.0) <= 40.0
    assert 1960.0 <= rate_map.pulse(0.999 * rate_map.upper.y[-1]).value <= 2000.0
