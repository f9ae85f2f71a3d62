"""The figures whatever matplotlib backend the environment names (found beside the tested path).

Every figure is drawn on an Agg canvas of its own, never through a backend, yet matplotlib checks
``MPLBACKEND`` as it is imported and raises ValueError for a name it does not know: ``hil report`` ended in
that traceback (exit 1), and ``hil run``'s plotter process died at its imports, so the run, which had
completed, ended in a BrokenPipeError's traceback when it handed the plotter its directory (exit 1, no
summary printed). Now the figures are drawn (:mod:`hil.plots` imports matplotlib with the variable set
aside), and a plotter that cannot import matplotlib at all says so after the run, as its error.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from montecarlo_support import write_quick_scenario

ROOT = Path(__file__).resolve().parents[1]
FIGURES = {"attitude_error.png", "pointing_error.png", "battery.png"}  # some of a default run's


def hil(*argv: str, **env: str) -> subprocess.CompletedProcess[str]:
    """``hil ARGV`` in a subprocess, ``env`` added to (or, when "", taken from) its environment."""
    environ = {**os.environ, **env}
    for name in [k for k, v in env.items() if v == ""]:
        del environ[name]
    return subprocess.run(
        [sys.executable, "-m", "hil", *argv], capture_output=True, text=True, timeout=300, cwd=ROOT,
        env=environ,
    )  # fmt: skip


@pytest.fixture(scope="module")
def quick(tmp_path_factory) -> Path:
    return write_quick_scenario(tmp_path_factory.mktemp("scenario"))


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory, quick) -> Path:
    """A real ``hil run``'s directory, its figures not drawn."""
    out = tmp_path_factory.mktemp("runs")
    done = hil("run", "--scenario", str(quick), "--out", str(out), "--no-plots")
    assert done.returncode == 0, done.stderr[-3000:]
    (d,) = out.iterdir()
    return d


def test_a_run_completes_and_draws_under_a_backend_matplotlib_does_not_know(tmp_path, quick):
    """``hil run`` under MPLBACKEND=no-such-backend: the run completes (exit 0) with its figures."""
    out = tmp_path / "runs"
    done = hil("run", "--scenario", str(quick), "--out", str(out), MPLBACKEND="no-such-backend")
    assert "Traceback" not in done.stderr, done.stderr[-3000:]
    assert done.returncode == 0, done.stderr[-3000:]
    (d,) = out.iterdir()
    assert FIGURES <= {p.name for p in (d / "plots").iterdir()}


@pytest.mark.parametrize("backend", ["no-such-backend", "TkAgg", "module://no_such_module", "Agg"])
def test_report_draws_a_run_whatever_backend_the_environment_names(run_dir, tmp_path, backend):
    """``hil report`` under MPLBACKEND naming no backend, one that needs a display there is not, a module
    that is not installed, and Agg: each redraws the run's figures, exit 0."""
    for png in (run_dir / "plots").glob("*.png") if (run_dir / "plots").is_dir() else ():
        png.unlink()
    done = hil("report", str(run_dir), MPLBACKEND=backend, DISPLAY="", WAYLAND_DISPLAY="")
    assert done.returncode == 0, done.stderr[-3000:]
    assert "Traceback" not in done.stderr
    assert FIGURES <= {p.name for p in (run_dir / "plots").iterdir()}


def test_report_draws_a_campaign_under_a_backend_matplotlib_does_not_know(tmp_path, quick):
    out = tmp_path / "mc"
    made = hil("montecarlo", str(quick), "--runs", "2", "--workers", "1", "--no-plots", "--out", str(out))
    assert made.returncode == 0, made.stderr[-3000:]
    done = hil("report", str(out), MPLBACKEND="no-such-backend")
    assert done.returncode == 0, done.stderr[-3000:]
    assert "Traceback" not in done.stderr
    assert {"histograms.png", "envelopes.png"} <= {p.name for p in (out / "plots").iterdir()}


def test_a_plotter_that_cannot_import_matplotlib_says_so_after_the_run(tmp_path, quick):
    """matplotlib broken in the environment (a package that fails at its import, found first on the path):
    the run runs, prints its summary, and ends saying its figures could not be drawn and why — exit 1
    (the run incomplete without its figures), never a BrokenPipeError's traceback."""
    broken = tmp_path / "site" / "matplotlib"
    broken.mkdir(parents=True)
    (broken / "__init__.py").write_text('raise ImportError("matplotlib: a broken install")\n')
    out = tmp_path / "runs"
    done = hil("run", "--scenario", str(quick), "--out", str(out), PYTHONPATH=str(broken.parent))
    assert "Traceback" not in done.stderr, done.stderr[-3000:]
    assert done.returncode == 1, done.stderr[-3000:]
    assert "run directory:" in done.stdout + done.stderr  # the summary was printed
    assert "plots: cannot draw figures: ImportError: matplotlib: a broken install" in done.stderr


@pytest.mark.parametrize("plot", [None, "fit.svg"])
def test_a_calibration_fit_plots_under_a_backend_matplotlib_does_not_know(tmp_path, plot):
    """``hil calibrate fit`` imported matplotlib itself, for the plot's format check and the plot: under
    MPLBACKEND=no-such-backend it ended in matplotlib's ValueError traceback. It fits, writes and plots."""
    from hil.calibration.generate import generate_bench

    generate_bench(tmp_path, 2, 3, (1,))
    csvs = [str(tmp_path / f"unit1_{kind}.csv") for kind in ("rotor", "gimbal_rate", "gimbal_angle")]
    more = ["--plot", str(tmp_path / plot)] if plot else []
    out = tmp_path / "cal.toml"
    done = hil("calibrate", "fit", *csvs, "-o", str(out), "--unit", "1", *more, MPLBACKEND="no-such-backend")
    assert "Traceback" not in done.stderr, done.stderr[-3000:]
    assert done.returncode == 0, done.stderr[-3000:]
    assert out.is_file() and (tmp_path / (plot or "cal-unit1.png")).stat().st_size > 1000
