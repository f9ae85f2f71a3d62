"""The fault campaigns' judge (:func:`hil.runtime.invariants.check_run`) beside phone clock jumps close
together: the host tells a jump by readings on the new clock (10 in a row, over 50 ms or more:
:mod:`hil.estimation.admission`), so a jump the clock moved on from within that time may never be told
— what the host can see is the clock before them all against the clock after.

What broke: each jump was expected on its own. A random probe drew a jump back 5 s and one forward 5 s
3 ms later — the phone's clock where it was — and failed the honest run for no ``phone_restart``.
"""

from __future__ import annotations

from hypothesis import example, given
from hypothesis import strategies as st

from hil.montecarlo.runner import fault_bounds
from hil.runtime.invariants import InjectedFault, check_run
from tests.fault_support import check_honest_end, faulted_run_settings, run_faults

SETTINGS = faulted_run_settings(8)
OFFSETS = st.sampled_from([-100.0, -5.0, 5.0, 100.0])


@SETTINGS
@given(
    first=OFFSETS,
    second=OFFSETS,
    apart_s=st.one_of(st.floats(0.0, 0.2), st.sampled_from([0.0, 0.003, 0.06, 0.2])),
    at=st.one_of(st.floats(0.5, 9.0), st.sampled_from([2.121, 3.681])),
)
@example(first=-5.0, second=5.0, apart_s=0.003, at=0.453)  # the probe's draw
@example(first=5.0, second=-5.0, apart_s=0.0, at=5.0)
def test_two_clock_jumps_close_together_are_judged_as_the_host_can_see_them(first, second, apart_s, at):
    """Two phone clock jumps within 0.2 s at a drawn moment of any phase: the honest run keeps every
    invariant (a pair that cancels out owes no report)."""
    t0 = round(at, 3)
    faults = [
        InjectedFault("phone_jump", t0, {"offset_s": first}),
        InjectedFault("phone_jump", round(t0 + apart_s, 3), {"offset_s": second}),
    ]
    sc, recorder = run_faults(faults)
    check_honest_end(faults, sc, recorder)


def test_a_pair_that_moves_the_clock_is_still_due_its_report():
    """Back 5 s, then forward 100 s 3 ms later: the clock moved 95 s ahead, and a record without the
    host's ``phone_jump`` report fails the judge."""
    faults = [
        InjectedFault("phone_jump", 5.0, {"offset_s": -5.0}),
        InjectedFault("phone_jump", 5.003, {"offset_s": 100.0}),
    ]
    sc, recorder = run_faults(faults)
    check_honest_end(faults, sc, recorder)
    journal = recorder.summary["faults"]
    recorder.summary["faults"] = [f for f in journal if f["kind"] not in ("phone_jump", "phone_restart")]
    assert check_run(faults, recorder, fault_bounds(sc)).violations["faults_detected"]
