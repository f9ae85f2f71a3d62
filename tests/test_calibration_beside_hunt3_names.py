"""``hil calibrate`` given names that are not UTF-8 text: a ``--name``, a bench CSV's file name, a
``--bench-dir`` or ``-o`` with a byte no UTF-8 decodes (Linux file names are bytes; Python hands them on as
surrogate escapes). The fit plot's text layout raised a ``TypeError`` and the calibration file's write a
``UnicodeEncodeError`` (tracebacks; in ``hil calibrate unit`` after the board was swept and uploaded).
Now a name no calibration file can hold is refused before any work, naming the option, and one that
is only shown (the plot's title) is shown with its escapes. Run as the real CLI, in subprocesses: the
arguments are bytes on its command line."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.calibration.files import load_calibration
from hil.calibration.generate import generate_bench

ROOT = Path(__file__).resolve().parents[1]
PNG = b"\x89PNG\r\n\x1a\n"

# a name with at least one byte that starts no UTF-8 sequence, among printable ASCII
undecodable = st.builds(
    lambda head, bad, tail: head + bytes([bad]) + tail,
    st.binary(max_size=4).map(lambda b: bytes(c for c in b if 0x41 <= c <= 0x7A)),
    st.integers(0x80, 0xFF).filter(lambda b: not 0xC2 <= b <= 0xF4),
    st.binary(max_size=4).map(lambda b: bytes(c for c in b if 0x41 <= c <= 0x7A)),
)


@pytest.fixture(scope="module")
def bench(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("bench")
    generate_bench(out, 1, 3, ())
    return out


def _hil(*args: bytes | str, cwd: Path) -> subprocess.CompletedProcess[bytes]:
    argv = [os.fsencode(sys.executable), b"-m", b"hil", *(os.fsencode(a) for a in args)]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(argv, cwd=cwd, env=env, capture_output=True, timeout=240, check=False)


def _clean_refusal(result: subprocess.CompletedProcess[bytes], option: bytes) -> None:
    assert result.returncode == 2, result.stderr.decode(errors="replace")[-3000:]
    assert b"Traceback" not in result.stderr
    assert option in result.stderr and b"not UTF-8 text" in result.stderr


@settings(max_examples=4, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(name=undecodable)
def test_a_name_that_is_not_utf8_is_refused_naming_the_option(bench, tmp_path_factory, name):
    tmp = tmp_path_factory.mktemp("name")
    out = tmp / "cal.toml"
    result = _hil(
        b"calibrate",
        b"fit",
        str(bench / "unit0_rotor.csv"),
        b"-o",
        str(out),
        b"--base",
        b"default",
        b"--name",
        name,
        cwd=tmp,
    )
    _clean_refusal(result, b"--name")
    assert sorted(p.name for p in tmp.iterdir()) == []  # nothing written, no temporary file left


@settings(max_examples=3, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(name=undecodable)
def test_a_bench_csv_named_with_a_byte_not_utf8_is_refused_before_the_fit(bench, tmp_path_factory, name):
    tmp = tmp_path_factory.mktemp("csv")
    csv = os.fsencode(tmp) + b"/" + name + b".csv"
    with open(csv, "wb") as f:
        f.write((bench / "unit0_rotor.csv").read_bytes())
    result = _hil(b"calibrate", b"fit", csv, b"-o", str(tmp / "cal.toml"), b"--base", b"default", cwd=tmp)
    _clean_refusal(result, b"the CSV")
    assert not (tmp / "cal.toml").exists()


def test_a_calibration_file_named_with_a_byte_not_utf8_is_written_and_plotted(bench, tmp_path):
    """Only the file's name is not text: the file holds none of it, so it is written, and its plot's
    title shows the byte as an escape (matplotlib refused the string: a traceback, nothing written)."""
    out = os.fsencode(tmp_path) + b"/cal\xff.toml"
    result = _hil(
        b"calibrate", b"fit", str(bench / "unit0_rotor.csv"), b"-o", out, b"--base", b"default", cwd=tmp_path
    )
    assert result.returncode == 0, result.stderr.decode(errors="replace")[-3000:]
    assert load_calibration(os.fsdecode(out)).unit(0) is not None
    with open(os.fsencode(tmp_path) + b"/cal\xff-unit0.png", "rb") as f:
        assert f.read(8) == PNG


def test_unit_refuses_a_bench_dir_not_utf8_before_the_board_is_driven(tmp_path):
    """``hil calibrate unit`` stores each CSV's path in the file: with a ``--bench-dir`` no file can hold,
    it swept, uploaded and verified, then its save raised (the board calibrated, no file, a traceback)."""
    bench_dir = os.fsencode(tmp_path) + b"/bench\xfe"
    result = _hil(
        b"calibrate",
        b"unit",
        b"--port",
        b"emu://",
        b"--unit",
        b"0",
        b"--maps",
        b"gimbal_angle",
        b"-o",
        str(tmp_path / "cal.toml"),
        b"--bench-dir",
        bench_dir,
        cwd=tmp_path,
    )
    _clean_refusal(result, b"--bench-dir")
    assert not os.path.exists(bench_dir) and not (tmp_path / "cal.toml").exists()
