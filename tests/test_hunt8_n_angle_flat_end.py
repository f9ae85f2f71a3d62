"""A gimbal-angle sweep whose angle goes flat at one end — the servo driven against its stop, or an angle
sensor that saturates — must be refused by ``hil calibrate fit``, naming the file and the end.

It was fitted: the table rose there by its minimum increments (1e-4 of the span per knot interval), the
residuals were small, the file was written, and a command near that angle put the servo anywhere on the
plateau, up to the end of the sweep: against its stop. (The rotor's flat top is refused so already.)
The data is the committed bench's, with its angle clipped at a drawn pulse; the command is the real one
(in process), its files real.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.cli import main

BENCH = Path(__file__).resolve().parents[1] / "fixtures" / "calibration" / "bench"


def _clipped(source: Path, out: Path, end: str, at_us: int) -> None:
    """``source`` with every angle beyond the one measured at ``at_us`` (towards ``end``) held at it."""
    lines = source.read_text().splitlines()
    rows = [line.split(",") for line in lines if line[:1].isdigit()]
    held = next(float(a) for p, _, a in rows if int(p) == at_us)
    out_lines = []
    for line in lines:
        if line[:1].isdigit():
            p, v, a = line.split(",")
            beyond = int(p) > at_us if end == "high" else int(p) < at_us
            line = f"{p},{v},{held if beyond else float(a):.4f}"
        out_lines.append(line)
    out.write_text("\n".join(out_lines) + "\n")


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    unit=st.sampled_from([0, 3]),  # unit 3's servo is mounted mirrored: its angle falls with the pulse
    end=st.sampled_from(["low", "high"]),
    travel_us=st.integers(min_value=3, max_value=32).map(lambda k: 25 * k),  # the plateau: 75..800 µs
)
def test_a_flat_end_of_an_angle_sweep_is_refused_naming_the_end(capsys, unit, end, travel_us):
    at_us = 2000 - travel_us if end == "high" else 1000 + travel_us
    with tempfile.TemporaryDirectory() as tmp:
        csv, out = Path(tmp) / "angle.csv", Path(tmp) / "cal.toml"
        _clipped(BENCH / f"unit{unit}_gimbal_angle.csv", csv, end, at_us)
        code = main(["calibrate", "fit", str(csv), "-o", str(out), "--base", "default"])
        err = capsys.readouterr().err
        assert code == 2, err
        assert f"{csv}: " in err and not out.exists(), err
        # a long plateau is data on no monotone curve (said so); a shorter one is a flat end, said so
        assert f"at the {end} end of the sweep" in err or "monotone" in err, err


def test_the_committed_angle_sweeps_still_fit(tmp_path, capsys):
    for unit in range(4):
        out = tmp_path / f"cal{unit}.toml"
        code = main(
            [
                "calibrate",
                "fit",
                str(BENCH / f"unit{unit}_gimbal_angle.csv"),
                "-o",
                str(out),
                "--base",
                "default",
            ]
        )
        assert code == 0, capsys.readouterr().err
