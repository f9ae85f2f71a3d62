"""Link outages over a long run: a rate fine for a minute is a flood over a day.

``outages_per_minute`` is bounded (0..600) but the count a run draws is that rate over the run's warm-up and
duration, which a scenario may make a day long: 600 a minute drew ~860 000 outages in every run — a 14 MB
``link.outage_list`` cell of ``runs.csv`` per run and as many ``--stall`` options handed to the board, the
draw alone taking seconds. A rate whose count could pass :data:`MAX_OUTAGES` is now refused as the file is
read, naming the file and the key; an accepted file's runs are never clipped.
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.montecarlo.dispersions import MAX_OUTAGES, draw, outage_window_s, parse_dispersions
from hil.scenario import SCENARIO_DIR, load_scenario
from protocol.errors import ConfigError

SCENARIO = load_scenario("cubesat-1u")

RATES = st.one_of(
    st.floats(0.0, 600.0).map(repr),
    st.tuples(st.floats(0.0, 300.0), st.floats(0.0, 300.0)).map(
        lambda ab: f"{{ dist = 'uniform', low = {ab[0]!r}, high = {ab[0] + ab[1] + 1e-3!r} }}"
    ),
    st.tuples(st.floats(0.0, 600.0), st.floats(0.0, 600.0)).map(
        lambda ms: f"{{ dist = 'normal', mean = {ms[0]!r}, sigma = {ms[1]!r}, low = 0.0 }}"
    ),
)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(rate=RATES, duration_s=st.floats(1.0, 86_000.0), index=st.integers(0, 10**6))
def test_a_run_s_outages_are_refused_or_bounded_never_clipped(rate, duration_s, index):
    """Any rate over any run length: refused at ``link.outages_per_minute`` naming the bound, or every
    run's outages fewer than :data:`MAX_OUTAGES` (so none was silently dropped)."""
    scenario = SCENARIO.with_changes(slew=dataclasses.replace(SCENARIO.slew, duration_s=duration_s))
    text = f"[link]\noutages_per_minute = {rate}\noutage_duration_s = 0.05\n"
    try:
        disp = parse_dispersions(text, scenario, "d.toml")
    except ConfigError as exc:
        assert exc.where == "d.toml: link.outages_per_minute", exc
        assert f"at most {MAX_OUTAGES}" in exc.detail
        return
    run = draw(disp, 11, index)
    assert len(run.outages) < MAX_OUTAGES
    assert all(0.0 <= start <= outage_window_s(scenario) for start, _ in run.outages)


@pytest.mark.parametrize("rate", ["600.0", "{ dist = 'normal', mean = 30.0, sigma = 5.0 }"])
def test_hil_montecarlo_refuses_a_day_of_outages_before_any_run(tmp_path, rate):
    """Through the command, on a day-long scenario: status 2, the file and key on stderr, no traceback, no
    campaign directory (and no 14 MB rows)."""
    text = (SCENARIO_DIR / "cubesat-1u.toml").read_text()
    assert "duration_s = 35.0" in text
    scenario = tmp_path / "day.toml"
    scenario.write_text(text.replace("duration_s = 35.0", "duration_s = 86000.0"))
    disp = tmp_path / "flood.toml"
    disp.write_text(f"[link]\noutages_per_minute = {rate}\noutage_duration_s = 0.05\n")
    out = tmp_path / "mc"
    done = subprocess.run(
        [sys.executable, "-m", "hil", "montecarlo", str(scenario), "--dispersions", str(disp), "--runs", "2",
         "--workers", "1", "--out", str(out), "--no-plots"],
        capture_output=True, text=True, timeout=240,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr[-2000:]
    assert "flood.toml: link.outages_per_minute" in done.stderr, done.stderr[-2000:]
    assert "Traceback" not in done.stderr
    assert not out.exists()
