"""The compiled kernels with the compiler switched off (``NUMBA_DISABLE_JIT=1``, hil.jit): the same code runs
as plain Python, slower, and still agrees with the numpy references — a smoke subset of the kernel tests,
run in a subprocess with the switch set, so CI checks the debugging path too."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import hil.jit

ROOT = Path(__file__).resolve().parent.parent

SMOKE = [
    "tests/test_jit_switch.py::test_the_switch_says_what_is_in_force",
    "tests/test_vscmg_compiled.py::test_random_states_one_step_and_a_hundred_equal_the_numpy_plant[1]",
    "tests/test_vscmg_compiled.py::test_drive_law_kernel_is_what_the_servo_model_computes[0.8]",
    "tests/test_vscmg_compiled.py::test_state_conversions_views_and_observed_runs",
    "tests/test_vscmg_compiled.py::test_bad_inputs_raise_as_the_reference_does",
    "tests/test_phone_model.py::test_body_phone_noise_is_the_seeded_generators_normal_draws_bit_for_bit",
    "tests/test_phone_model.py::test_body_phone_refuses_a_bad_path",
    "tests/test_firmware_sim_world.py::test_a_short_world_run_equals_the_reference_world",
    "tests/test_estimator.py::test_every_form_of_a_sample_gives_the_same_step_and_a_bad_one_a_named_error",
]


def test_the_switch_says_what_is_in_force():
    assert hil.jit.COMPILED == (os.environ.get("NUMBA_DISABLE_JIT", "0") in ("", "0"))


def test_the_smoke_subset_passes_with_the_compiler_switched_off():
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    proc = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *SMOKE],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-2000:]
    assert f"{len(SMOKE)} passed" in proc.stdout


LAZY = """
from hil.estimation import chain, variational
from hil.estimation.estimator import VariationalEstimator
from hil.estimation.filter import AttitudeFilter, FilterConfig

VariationalEstimator()
AttitudeFilter(FilterConfig.tuned())
print(variational.update.versions, chain.step.versions)
VariationalEstimator().update(0.01, [0, 0, 0], [0, 0, 9.8], [0, 20, -40])
print(variational.update.versions, chain.step.versions)
"""


def test_a_per_sample_kernel_is_bound_at_its_first_call_not_at_construction():
    """hil.jit.direct binds a kernel's machine code for fixed argument types (loading or compiling it): the
    estimator and the filter do it at their first per-sample call, not when they are made, so one that
    only runs batches (a replay) or one inside a filter (the filter steps its estimator within its own
    kernel) never loads, or on a fresh install compiles (~7-10 s), a kernel it does not call."""
    if not hil.jit.COMPILED:
        return
    proc = subprocess.run([sys.executable, "-c", LAZY], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.split() == ["0", "0", "1", "0"], proc.stdout
