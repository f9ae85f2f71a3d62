"""``hil run --out ROOT`` whose ROOT is a name beside the tested ones (a hunt's findings), through the real
command: the run's plots are drawn by a second process (``python -m hil.cli._plotter``) that is handed the
run directory's path on a pipe. It took the first line of it with the spaces at both ends stripped, so a
run under ``" runs"`` or ``"runs "`` (or a name with a line break in it) had its plots drawn from another
directory — none there: ``hil run: plots: ... no such file (telemetry)``, exit status 1, no figures, for a
run that completed — and a path the user could name was never one the plotter could read."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

NOT_UTF8 = {**os.environ, "LC_ALL": "C", "PYTHONUTF8": "0", "PYTHONIOENCODING": ""}
NAMES = [
    (" leading space", None),
    ("two\nlines", None),
    ("ünïcödé runs ✓", None),
    (os.fsdecode(b"not utf-8 \xff\xfe"), None),  # a name of bytes no encoding decodes (it was a traceback)
    ("ünïcödé runs ✓", NOT_UTF8),  # a C locale's file names: the run's name handed over as its bytes
]


@pytest.mark.parametrize(("name", "env"), NAMES)
def test_a_run_under_any_directory_name_gets_its_plots(tmp_path, name, env):
    """``--out`` relative, as a user types it: the run directory's path then begins with the name."""
    out = tmp_path / name
    done = subprocess.run(
        [sys.executable, "-m", "hil", "run", "--duration", "1", "--out", name],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        encoding="utf-8",
        errors="backslashreplace",
        env=env,
        timeout=300,
    )
    assert "Traceback" not in done.stderr, done.stderr[-2000:]
    assert done.returncode == 0, done.stderr[-2000:]
    assert "no such file" not in done.stderr
    (run_dir,) = out.iterdir()
    drawn = {p.name for p in (run_dir / "plots").glob("*.png")}
    assert {"pointing_error.png", "gimbal_rates.png", "attitude_error.png"} <= drawn, drawn
