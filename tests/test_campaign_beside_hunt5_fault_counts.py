"""A fault count written as a fraction: ``hang = { count = 0.5 }`` was rounded half to even, to 0.

A count as written (a number, a choice's values, a normal of no spread) was rounded silently: 0.5 (or 0.4)
hangs was none in every run — a fault campaign that injected nothing and said every run kept its
invariants — 2.5 was two and 3.5 four. It is now refused as the file is read, naming the file and the key;
a distribution's draws are still rounded to a whole count, as the docs say.
"""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.montecarlo.dispersions import draw, parse_dispersions
from hil.scenario import load_scenario
from protocol.errors import ConfigError

SCENARIO = load_scenario("cubesat-1u")
FRACTIONS = st.floats(0.0, 100.0).filter(lambda v: v != round(v))


@settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    count=FRACTIONS,
    form=st.sampled_from(["fixed", "choice", "normal"]),
    kind=st.sampled_from(["hang", "brownout", "abort"]),
    wholes=st.lists(st.integers(0, 100), max_size=3),
)
def test_a_fractional_count_as_written_is_refused_naming_the_key(count, form, kind, wholes):
    written = {
        "fixed": repr(count),
        "choice": f"{{ dist = 'choice', values = [{', '.join(map(repr, [*wholes, count]))}] }}",
        "normal": f"{{ dist = 'normal', mean = {count!r}, sigma = 0.0 }}",
    }[form]
    with pytest.raises(ConfigError) as info:
        parse_dispersions(f"[faults]\n{kind} = {{ count = {written} }}\n", SCENARIO, "f.toml")
    assert info.value.where == f"f.toml: faults.{kind}.count", info.value
    assert "whole number" in info.value.detail


@pytest.mark.parametrize("count", ["0", "3", "{ dist = 'choice', values = [0, 1, 2] }",
                                   "{ dist = 'uniform', low = 0.0, high = 4.0 }"])  # fmt: skip
def test_whole_counts_and_rounded_draws_still_load(count):
    disp = parse_dispersions(f"[faults]\nhang = {{ count = {count} }}\n", SCENARIO, "f.toml")
    for index in range(5):
        faults = draw(disp, 2, index).faults
        assert faults is not None and len(faults) <= 4


def test_hil_montecarlo_refuses_half_a_hang_before_any_run(tmp_path):
    """Through the command: status 2 and the key named, not a campaign of runs given no fault at all."""
    disp = tmp_path / "half.toml"
    disp.write_text("[faults]\nhang = { count = 0.5 }\n")
    out = tmp_path / "mc"
    done = subprocess.run(
        [sys.executable, "-m", "hil", "montecarlo", "cubesat-1u", "--dispersions", str(disp), "--runs", "2",
         "--workers", "1", "--out", str(out), "--no-plots"],
        capture_output=True, text=True, timeout=240,
    )  # fmt: skip
    summary = out / "summary.json"
    injected = json.loads(summary.read_text()).get("faults_injected") if summary.exists() else None
    assert done.returncode == 2, (done.stderr[-1500:], injected)
    assert "half.toml: faults.hang.count" in done.stderr, done.stderr[-1500:]
    assert "Traceback" not in done.stderr
    assert not out.exists()


@pytest.mark.parametrize("duration_s", [35.0, 600.0, 86_000.0])
def test_a_fault_rate_is_what_runs_get_or_refused_naming_the_key(duration_s):
    """``stall = { per_minute = 600 }`` gave exactly MAX_COUNT (100) stalls in every default run: ~154 a
    minute, no Poisson spread, unsaid. A rate whose count could pass the bound is refused with the rate that
    fits; the largest rate that fits is taken, and its runs' counts spread about its mean."""
    from hil.montecarlo import draw, parse_dispersions
    from hil.montecarlo.fault_plan import MAX_COUNT, _largest_rate, run_window_s
    from hil.scenario import load_scenario
    from protocol.errors import ConfigError

    base = load_scenario()
    scenario = base.with_changes(slew=dataclasses.replace(base.slew, duration_s=duration_s))
    fits = _largest_rate(run_window_s(scenario))
    with pytest.raises(ConfigError, match=r"faults\.stall\.per_minute") as refused:
        parse_dispersions(
            f"[faults]\nstall = {{ per_minute = {fits * 1.01!r}, duration_s = 0.1 }}\n", scenario, "f.toml"
        )
    assert f"at most {fits:.3g} a minute here" in str(refused.value)
    dispersions = parse_dispersions(
        f"[faults]\nstall = {{ per_minute = {fits * 0.99!r}, duration_s = 0.1 }}\n", scenario, "f.toml"
    )
    counts = [len(draw(dispersions, 0, index).faults or ()) for index in range(20)]
    assert max(counts) < MAX_COUNT and len(set(counts)) > 1
