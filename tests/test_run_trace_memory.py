"""The run's per-tick trace (:class:`hil.runtime.telemetry.RunTrace`, one value of each of 6 figures per
control tick from the slew's start) once held lists of Python floats: ~32 bytes a value (a float object and
the list's pointer), not the 8 its docstring said — a host's memory grew ~39 MB an hour of a 50 Hz run.
Now each figure is an ``array('d')``: 8 bytes a value, read as the lists were (length, index, iteration,
numpy), and :meth:`RunTrace.arrays` copies (a numpy view would stop the array growing: ``BufferError``).
"""

from __future__ import annotations

import math
import tracemalloc

import numpy as np
import pytest
from fault_support import short_scenario
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.runtime import RunOptions, run
from hil.runtime.telemetry import RunTrace


@pytest.mark.parametrize("ticks", [20_000, 180_000])  # ~7 min and ~1 h of a 50 Hz run
def test_the_trace_takes_8_bytes_a_value(ticks):
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        trace = RunTrace()
        for k in range(ticks):
            x = k * 0.02 + 0.001  # distinct floats: none shared or cached
            trace.append(x, x + 1.0, x + 2.0, x + 3.0, x + 4.0, x + 5.0)
        grown = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    per_value = grown / (6 * ticks)
    assert per_value <= 10.0, f"{per_value:.1f} bytes a value"  # 8, and the array's over-allocation
    assert len(trace) == ticks and trace.t[-1] == pytest.approx((ticks - 1) * 0.02 + 0.001)


@settings(max_examples=30, deadline=None)
@given(values=st.lists(st.tuples(*[st.floats(allow_nan=True, allow_infinity=False)] * 6), max_size=200))
def test_the_trace_reads_as_the_lists_did_and_grows_after_its_arrays_are_taken(values):
    trace = RunTrace()
    for v in values:
        trace.append(*v)
    taken = trace.arrays()  # held while the trace grows on: a copy, never a view of its buffer
    trace.append(1.0, 2.0, 3.0, 4.0, 5.0, 6.0)
    for i, name in enumerate(RunTrace.FIELDS):
        seq = getattr(trace, name)
        expected = [v[i] for v in values] + [float(i + 1)]
        assert len(seq) == len(expected) and bool(seq)
        assert all(a == b or (math.isnan(a) and math.isnan(b)) for a, b in zip(seq, expected, strict=True))
        assert seq[-1] == expected[-1]
        np.testing.assert_array_equal(taken[name], np.array(expected[:-1], dtype=float))


def test_a_run_s_trace_and_figures_from_it():
    """Through a run: every figure a sequence as long as the run's ticks since the slew, its summary's
    figures those of its trace."""
    result = run(short_scenario(), RunOptions(out_root=None))
    trace, s = result.trace, result.summary
    n = len(trace)
    assert n > 100 and all(len(getattr(trace, name)) == n for name in RunTrace.FIELDS)
    assert s["final_error_deg"] == pytest.approx(trace.point_err_deg[-1])
    assert s["peak_gimbal_rate"] == pytest.approx(np.nanmax(trace.gimbal_rate))
    assert s["estimator_rmse_deg"] is not None and s["estimator_rmse_deg"] > 0
