"""A user's estimator whose batch ``run`` never returns ends ``hil replay`` (the batch path, and the paced
one's ``step``) with a :class:`~hil.plugins.PluginTimeout` naming the estimator and the call, status 2 —
as a run's live calls are bounded (tests/test_plugins_beside_hunt6_blocking_step.py). Through real ``hil``
processes, a real dist-info on ``sys.path`` and the real Sensor Logger export cut short.

Before: ``hil replay LOG --estimator blocking`` hung until it was killed (the batch ``run`` was called
directly, unbounded)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from hil.estimation.checked import FIRST_CALL_WAIT_S, RUN_WAIT_PER_STEP_S, run_bound_s
from tests.log_support import needs_real_export, real_export

REPO = Path(__file__).resolve().parents[1]
PLUGIN = "blocking_hunt7_batch_plug"
SHORT_BOUND = (
    "import hil.estimation.checked as c; c.FIRST_CALL_WAIT_S = 1.0; c.RUN_WAIT_PER_STEP_S = 0.0001; "
    "c.STEP_WAIT_FLOOR_S = 1.0; "
)


@pytest.fixture
def installed(tmp_path: Path) -> Path:
    (tmp_path / f"{PLUGIN}.py").write_text(textwrap.dedent('''
        import os
        import threading
        import time

        from hil.estimation.variational_kind import VARIATIONAL

        class Blocking:
            def __init__(self, inner, how):
                self.inner, self.how = inner, how

            def step(self, s):
                if self.how == "step":
                    threading.Event().wait()  # never set: blocked in C
                return self.inner.step(s)

            def run(self, steps, progress=None):
                if self.how == "run":
                    threading.Event().wait()
                if self.how == "slow":
                    time.sleep(0.5)  # slow, but it returns within its bound
                return self.inner.run(steps, progress)

            @property
            def gyro_bias(self):
                return self.inner.gyro_bias

            def set_gyro_bias(self, b):
                self.inner.set_gyro_bias(b)

            def set_rest_learning(self, on):
                self.inner.set_rest_learning(on)

        class Kind:
            keys = frozenset({"preset"})
            name = "blocking"

            def check(self, settings, where):
                return VARIATIONAL.check(settings, where)

            def build(self, settings, site):
                return Blocking(VARIATIONAL.build(settings, site), os.environ["HUNT7_BLOCK"])

            def describe(self, settings):
                return "the variational estimator, until it blocks"

        KIND = Kind()
    '''))  # fmt: skip
    info = tmp_path / "blocking_hunt7_batch-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: blocking_hunt7_batch\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(f"[vscmg_hil.estimators]\nblocking = {PLUGIN}:KIND\n")
    real_export(tmp_path / "log")
    return tmp_path


def _replay(root: Path, block: str, *args: str, bound: str = SHORT_BOUND) -> subprocess.CompletedProcess[str]:
    path = [str(root), str(REPO)]
    script = (
        f"import sys; sys.path[:0] = {path!r}; {bound}from hil.cli import main; sys.exit(main(sys.argv[1:]))"
    )
    env = {**os.environ, "HUNT7_BLOCK": block}
    return subprocess.run(
        [sys.executable, "-c", script, "replay", str(root / "log"), "--estimator", "blocking", "--no-plots",
         "--out", str(root / "out"), *args],
        capture_output=True, text=True, timeout=120, cwd=root, env=env,
    )  # fmt: skip


@needs_real_export
def test_a_batch_run_that_never_returns_ends_the_replay_as_an_error_naming_it(installed):
    run = _replay(installed, "run")
    assert run.returncode == 2, (run.returncode, run.stderr[-3000:])
    assert "hil replay: error: estimator 'blocking': run over " in run.stderr, run.stderr[-3000:]
    assert "did not return within" in run.stderr, run.stderr[-3000:]
    assert "Traceback" not in run.stderr, run.stderr
    assert not (installed / "out" / "estimates.csv").exists()


@needs_real_export
def test_a_paced_replays_step_that_never_returns_is_an_error_naming_it(installed):
    run = _replay(installed, "step", "--paced")
    assert run.returncode == 2, (run.returncode, run.stderr[-3000:])
    assert "hil replay: error: estimator 'blocking': step at t = " in run.stderr, run.stderr[-3000:]
    assert "did not return within" in run.stderr and "Traceback" not in run.stderr, run.stderr


@needs_real_export
def test_a_slow_batch_within_its_bound_is_waited_for(installed):
    # the bound is long enough for the built-in kernels to load in a fresh process; the 0.5 s is waited for
    run = _replay(
        installed,
        "slow",
        bound=SHORT_BOUND.replace("c.FIRST_CALL_WAIT_S = 1.0", "c.FIRST_CALL_WAIT_S = 120.0"),
    )
    assert run.returncode == 0, run.stderr[-3000:]
    assert (installed / "out" / "estimates.csv").is_file()


def test_the_batch_bound_grows_with_the_steps():
    assert run_bound_s(0) == FIRST_CALL_WAIT_S
    assert run_bound_s(400_000) == FIRST_CALL_WAIT_S + 400_000 * RUN_WAIT_PER_STEP_S
    assert run_bound_s(10) < run_bound_s(10_000)
