"""The simulated phone and the plant at times far from zero, where float64 no longer resolves a sample period
or a step: at 1e16 s the phone's next sample time did not move when its period was added and
``BodyPhone.sample`` never returned (its compiled twin refused with an opaque "status -2"); at 1e17 s a
plant step of 1 ms left the plant's clock where it was, the numpy and the compiled plant alike.

Now a time beyond ±MAX_TIME_S (2³³ s, ~272 years, where float64 still keeps 1 µs) is a ConfigError naming
where, before anything is sampled or stepped; times within it sample and step as before. The hang is run in
a subprocess with a deadline, never in pytest's own process.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_sim.world.models.compiled import CompiledPlant
from firmware_sim.world.models.kernels import MAX_TIME_S
from firmware_sim.world.models.phone import BodyPhone
from firmware_sim.world.models.plant import Plant
from hil.vscmg import cubesat_1u
from protocol.errors import ConfigError

PLANT = Plant(cubesat_1u())
COMPILED = CompiledPlant(PLANT)

far = st.floats(MAX_TIME_S * 1.0001, 1e300) | st.sampled_from([1e16, 1e17, float("inf"), float("nan")])
signs = st.sampled_from([1.0, -1.0])


def _level_path(t0: float, t1: float) -> np.ndarray:
    path = np.zeros((2, 13))
    path[:, [1, 5, 9]] = 1.0  # R = I
    path[:, 0] = t0, t1
    return path


SAMPLE_FAR = textwrap.dedent(
    """
    import numpy as np
    from firmware_sim.world.models.phone import BodyPhone
    from protocol.errors import ConfigError
    try:
        phone = BodyPhone()
        phone.sample(1e16, np.eye(3), np.zeros(3), 1e16 + 0.05, np.eye(3), np.zeros(3))
    except ConfigError as e:
        print("refused:", e)
    """
)


def test_sampling_a_phone_at_a_far_time_ends_with_an_error_naming_it():
    """The numpy sampler looped for ever at 1e16 s; now it refuses at once (in a subprocess: the old code
    hangs)."""
    done = subprocess.run(
        [sys.executable, "-c", SAMPLE_FAR], capture_output=True, text=True, timeout=120, check=False
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert "refused: BodyPhone.sample.t0" in done.stdout, done.stdout


@settings(max_examples=30, deadline=None)
@given(t=far, sign=signs)
def test_a_phone_started_or_sampled_beyond_the_far_time_is_refused_naming_where(t, sign):
    t = sign * t
    with pytest.raises(ConfigError, match="BodyPhone.t0"):
        BodyPhone(t0=t)
    phone = BodyPhone()
    with pytest.raises(ConfigError, match="BodyPhone.sample_path"):
        phone.sample_path(_level_path(0.0, t) if sign > 0 else _level_path(t, 0.0))
    with pytest.raises(ConfigError, match=r"BodyPhone\.sample\.t"):
        phone.sample(0.0, np.eye(3), np.zeros(3), t, np.eye(3), np.zeros(3))


@settings(max_examples=30, deadline=None)
@given(t=far, sign=signs)
def test_a_plant_stepped_to_or_from_beyond_the_far_time_is_refused_by_both_plants(t, sign):
    s = PLANT.state(t=sign * t)
    with pytest.raises(ConfigError, match=r"Plant\.step\.t"):
        PLANT.step(s, 1e-3)
    flat = COMPILED.pack(s)
    before = flat.copy()
    with pytest.raises(ConfigError, match=r"CompiledPlant\.advance\.t"):
        COMPILED.advance(flat, 1e-3, 3)
    np.testing.assert_array_equal(flat, before)


def test_a_run_of_steps_that_would_cross_the_far_time_is_refused_before_its_first_step():
    flat = COMPILED.pack(PLANT.state(t=MAX_TIME_S - 1.0))
    with pytest.raises(ConfigError, match="beyond"):
        COMPILED.advance(flat, 1e-3, 2000)  # ends 1 s past it


@settings(max_examples=20, deadline=None)
@given(t0=st.floats(-MAX_TIME_S + 1.0, MAX_TIME_S - 1.0))
def test_within_the_far_time_a_step_moves_the_clock_by_its_length_to_a_microsecond(t0):
    s = PLANT.state(t=t0)
    assert abs(PLANT.step(s, 1e-3).t - t0 - 1e-3) <= 1e-6
    flat = COMPILED.pack(s)
    COMPILED.advance(flat, 1e-3, 1)
    assert abs(flat[0] - t0 - 1e-3) <= 1e-6


@settings(max_examples=20, deadline=None)
@given(t0=st.floats(0.0, MAX_TIME_S - 1.0))
def test_within_the_far_time_both_samplers_take_the_same_samples(t0):
    a, b = BodyPhone(t0=t0), BodyPhone(t0=t0)
    reference = a.sample(t0, np.eye(3), np.zeros(3), t0 + 0.05, np.eye(3), np.zeros(3))
    compiled = b.sample_path(_level_path(t0, t0 + 0.05))
    assert 20 <= len(reference) <= 26
    assert [(x.kind, x.t_s) for x in compiled] == [(x.kind, x.t_s) for x in reference]
