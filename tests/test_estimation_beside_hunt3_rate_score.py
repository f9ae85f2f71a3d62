"""A replay's rate error against ground truth is scored where its attitude error is, and only from truth
that has a rate to give.

``hil replay`` prints, and writes to ``summary.json``, "rate error RMS" beside the attitude's RMSE. The
attitude was scored within the parts of the log the filter ran over only (:meth:`hil.logs.replay.
ReplayResult.replayed`), the rate over every truth midpoint: across a gap the rate "estimate" was the two
parts' ends joined by interpolation, and a 20 s gap in the 4 s simulated fixture raised the printed rate RMS
from 0.007 to 0.57 rad/s against a filter that did as well on both sides. The truth's own rate was
differentiated across its gaps (a rotation ``log`` folds into ±π, over seconds), duplicated stamps (an
infinite rate) and stamps going back (the rate reversed).
"""

from __future__ import annotations

import re
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st
from test_replay_beside_gap_figures import gapped_log

from hil import so3
from hil.estimation.metrics import truth_rates
from hil.estimation.sensors import MAX_PAUSE_S

UNGAPPED_RATE_RMS = 0.0074  # rad/s: the fixture replayed whole (measured)


def _replay_rate_rms(log: Path, out: Path) -> float:
    run = subprocess.run(
        [sys.executable, "-m", "hil", "replay", str(log), "--out", str(out), "--no-plots"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert run.returncode == 0, run.stdout + run.stderr
    said = re.search(r"rate error RMS (\S+) rad/s", run.stdout)
    assert said is not None, run.stdout
    return float(said[1])


@settings(
    max_examples=3,
    deadline=None,
    phases=(Phase.explicit, Phase.reuse, Phase.generate),  # each example a replay's subprocess: no shrinking
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(at_s=st.floats(1.2, 2.8), gap_s=st.floats(3.0, 40.0))
def test_hil_replay_s_rate_error_leaves_out_a_gap_the_filter_did_not_run_over(tmp_path_factory, at_s, gap_s):
    folder = tmp_path_factory.mktemp("gap")
    rms = _replay_rate_rms(gapped_log(folder, at_s, gap_s), folder / "out")
    assert rms < 3 * UNGAPPED_RATE_RMS, rms  # 0.57 rad/s when scored across the gap


def test_the_truth_has_no_rate_across_its_gaps_duplicates_or_stamps_going_back():
    """A truth turning at 1 rad/s about z, 100 Hz, with a 4 s gap, a duplicated stamp and a stamp going
    back: the rate is 1 rad/s wherever a pair's stamps move forward (by at most MAX_PAUSE_S), unknown (NaN)
    at the three others — never the folded −0.57 rad/s, an infinite or a reversed rate — and computing
    it warns of nothing."""
    t = np.r_[np.arange(0.0, 1.0, 0.01), np.arange(5.0, 6.0, 0.01)]
    t = np.r_[t[:150], t[149], t[150:]]  # a duplicated stamp
    t = np.r_[t[:170], t[168], t[170:]]  # a stamp going back (then on again)
    r = np.stack([so3.exp(np.array([0.0, 0.0, float(x)])) for x in t])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mid, omega = truth_rates(t, r)
    dt = np.diff(t)
    unknown = np.flatnonzero(~((dt > 0) & (dt <= MAX_PAUSE_S)))
    assert len(unknown) == 3  # the gap, the duplicate, the step back
    assert np.all(np.isnan(omega[unknown]))
    known = np.delete(omega, unknown, axis=0)
    np.testing.assert_allclose(known, np.tile([0.0, 0.0, 1.0], (len(known), 1)), atol=1e-9)
