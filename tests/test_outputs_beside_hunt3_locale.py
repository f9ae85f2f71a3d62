"""A run and its report in a locale whose encoding is not UTF-8 (a hunt's finding), through the real
commands; ``LC_ALL=C PYTHONUTF8=0`` (ASCII) stands for any of them (a Latin-1 locale: the same refusals for
the characters it lacks). Every file a run writes is UTF-8 whatever the locale, and every name is one the file
system can hold:

1. the run's copy of its scenario (``scenario.toml``) was written in the locale's encoding: the ``°`` in a
   shipped scenario's comments (the default ``hil run``'s too) was a ``UnicodeEncodeError``'s traceback,
   the run ended before its first row (and in a Latin-1 locale a TOML file no reader takes);
2. a scenario named with a letter the file system's encoding lacks was a ``UnicodeEncodeError``'s traceback
   from making the run directory;
3. ``hil report`` took print's ``UnicodeEncodeError`` for a ``δ`` the terminal cannot show as a damaged
   summary.json: "summary.json damaged ...: not shown", for a run's own summary.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NOT_UTF8 = {**os.environ, "LC_ALL": "C", "PYTHONUTF8": "0", "PYTHONIOENCODING": ""}


def _hil(*argv: str, cwd: Path, env: dict[str, str] = NOT_UTF8) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "hil", *argv],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        encoding="utf-8",
        errors="backslashreplace",
        timeout=300,
    )


@pytest.mark.parametrize("name", [None, "cubesat ü ✓ 立方体"])
def test_a_run_and_its_report_in_a_locale_that_is_not_utf8(tmp_path, name):
    source = (ROOT / "fixtures" / "scenarios" / "cubesat-1u.toml").read_text(encoding="utf-8")
    assert "°" in source  # what the locale's encoding cannot hold
    if name is not None:
        lines = source.splitlines(keepends=True)
        at = next(i for i, line in enumerate(lines) if line.startswith("name ="))
        source = "".join([*lines[:at], f'name = "{name}"\n', *lines[at + 1 :]])
    scenario = tmp_path / "scenario.toml"
    scenario.write_text(source, encoding="utf-8")
    out = tmp_path / "runs"
    done = _hil(
        "run", "--scenario", str(scenario), "--duration", "1", "--no-plots", "--out", str(out), cwd=tmp_path
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert "Traceback" not in done.stderr, done.stderr[-2000:]
    # the run's own summary printed (its print's UnicodeEncodeError, a ValueError, was passed over whole)
    assert "final error" in done.stdout and "exit" in done.stdout, done.stdout[-2000:]
    (run_dir,) = out.iterdir()
    assert (run_dir / "scenario.toml").read_text(encoding="utf-8") == source
    assert (run_dir / "summary.json").is_file() and (run_dir / "telemetry.csv").is_file()

    report = _hil("report", "--no-plots", str(run_dir), cwd=tmp_path)
    assert report.returncode == 0, report.stderr[-2000:]
    assert "damaged" not in report.stdout, report.stdout
    assert "minimum delta" in report.stdout and "exit              completed" in report.stdout, report.stdout


def test_a_run_under_a_name_not_utf8_says_its_directory_on_a_strict_utf8_stdout(tmp_path):
    """``PYTHONIOENCODING=utf-8`` (strict errors, as a service or a CI runner sets it): the run directory's
    name holds a byte no encoding decodes, kept as a lone surrogate that no encoding writes; its
    ``print`` raised, the guard against a hung-up terminal passed it over, and the summary's last line —
    where the run is — went unprinted. Now it is written as an escape."""
    name = os.fsdecode(b"runs \xff")
    env = {**os.environ, "PYTHONIOENCODING": "utf-8"}
    done = _hil("run", "--duration", "1", "--no-plots", "--out", name, cwd=tmp_path, env=env)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "run directory: runs \\udcff/" in done.stdout, done.stdout[-2000:]
