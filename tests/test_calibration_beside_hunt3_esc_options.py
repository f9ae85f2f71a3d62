"""``hil calibrate esc`` and ``unit --program-esc`` given a step the ``EscCalibrate`` command cannot carry
(a negative ``--high-ms``, a ``--supply-off-ms`` of years, an endpoint outside 500..2500 µs): refused
before the board is opened, naming the option. It was found when the command was encoded — the board
opened and put to rest, the error naming the wire's field ``EscCalibrate.high_ms``. The real CLI, in
subprocesses, against the emulator (``emu://``)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

ROOT = Path(__file__).resolve().parents[1]

# (option, a value its EscCalibrate field cannot carry: below or above the wire's range)
beyond = st.one_of(
    st.tuples(st.just("--high-ms"), st.one_of(st.integers(-(10**9), 99), st.integers(20_001, 10**12))),
    st.tuples(st.just("--low-ms"), st.one_of(st.integers(-(10**9), 99), st.integers(20_001, 10**12))),
    st.tuples(st.just("--supply-off-ms"), st.one_of(st.integers(-(10**9), -1), st.integers(10_001, 10**12))),
    st.tuples(st.just("--esc-low"), st.integers(-(10**6), 499)),
)


def _hil(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, "-m", "hil", *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=240
    )


@settings(max_examples=4, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(bad=beyond)
def test_esc_step_beyond_the_command_is_refused_naming_the_option(tmp_path_factory, bad):
    option, value = bad
    tmp = tmp_path_factory.mktemp("esc")
    result = _hil(
        "calibrate",
        "esc",
        "--port",
        "emu://",
        "--unit",
        "0",
        "--confirm-unloaded",
        f"{option}={value}",
        cwd=tmp,
    )
    assert result.returncode == 2, result.stderr[-2000:]
    assert f"error: {option}: {value} is outside" in result.stderr
    assert "left" not in result.stderr  # refused before the board was opened: nothing put to rest


def test_unit_program_esc_refuses_it_before_the_board_is_driven(tmp_path):
    result = _hil(
        "calibrate", "unit", "--port", "emu://", "--unit", "0", "--program-esc", "--confirm-unloaded",
        "--high-ms", "-1", "-o", str(tmp_path / "cal.toml"), "--bench-dir", str(tmp_path / "bench"),
        cwd=tmp_path,
    )  # fmt: skip
    assert result.returncode == 2, result.stderr[-2000:]
    assert "error: --high-ms: -1 is outside" in result.stderr and "left" not in result.stderr
    assert not (tmp_path / "bench").exists()
