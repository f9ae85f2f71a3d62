"""A normal's own clip bounds that take (nearly) every draw, and a duration of 0 hidden in a choice.

``{ dist = "normal", sigma = 0.01, low = 2 }`` on an inertia scale (nominal 1) is a truncated normal 100 σ
out: every draw was clipped to 2, so every run flew a fixed inertia of twice the scenario's, with a
"dispersed" column that never varied; a fault count ``{ mean = 1, sigma = 0.5, low = 50 }`` gave every run
50 hangs. A σ wider than ``high - low`` did the same to the two ends. Both are now refused as the file is
read, naming the file and the key; a mean within the bounds and a σ within them still disperse.

A stall's ``duration_s = { dist = "choice", values = [0.0, 1.0] }`` (or a link outage's) slipped past the
"a fault of no time is none" check that a fixed 0 gets: half the runs were given 1 ms stalls nobody asked
for. Any value of 0 as written is now refused.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.montecarlo.dispersions import draw, parse_dispersions
from hil.scenario import load_scenario
from protocol.errors import ConfigError

SCENARIO = load_scenario("cubesat-1u")
QUICK = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])

# (table, key, nominal mean, the parameter's own range): a dispersion, and a fault kind's count/parameter
TARGETS = [
    ("spacecraft", "inertia_scale", 1.0, (-100.0, 100.0)),
    ("initial", "angle_deg", 0.0, (-360.0, 360.0)),
    ("faults.hang", "count", 0.0, (0.0, 100.0)),
    ("faults.stall", "duration_s", 0.0, (0.0, 60.0)),
]


def _file(table: str, key: str, dist: str) -> str:
    if table.startswith("faults."):
        kind = table.split(".")[1]
        extra = "" if key == "count" else "count = 1, "
        extra += "" if kind != "stall" or key == "duration_s" else "duration_s = 1.0, "
        return f"[faults]\n{kind} = {{ {extra}{key} = {dist} }}\n"
    return f"[{table}]\n{key} = {dist}\n"


def _column_draws(text: str, key: str, runs: int = 40) -> np.ndarray:
    """The drawn values of ``key`` (a dispersion's column, or a fault count/duration) over ``runs`` runs."""
    disp = parse_dispersions(text, SCENARIO, "f.toml")
    out = []
    for i in range(runs):
        run = draw(disp, 3, i)
        if run.faults is None:
            out += [float(v) for k, v in run.columns.items() if k.split(".")[1] == key.split(".")[0]]
        elif key == "count":
            out.append(float(len(run.faults)))
        else:
            out += [float(f.params[key]) for f in run.faults]
    return np.array(out)


@QUICK
@given(
    target=st.sampled_from(TARGETS),
    sigma=st.floats(1e-3, 1.0),
    sigmas_out=st.floats(1.01, 1e6),
    above=st.booleans(),
    with_mean=st.booleans(),
)
def test_a_normal_whose_clip_bounds_lie_beside_its_mean_is_refused_naming_the_bound(
    target, sigma, sigmas_out, above, with_mean
):
    """Clip bounds drawn wholly on one side of the mean, from 1 σ to 10⁶ σ out (within the parameter's
    range): refused at ``KEY.low``/``KEY.high``, never a campaign flying the bound in every run."""
    table, key, nominal, (lo, hi) = target
    mean = nominal if not with_mean else (lo + hi) / 2.0
    span = hi - lo
    gap = min(sigmas_out * sigma, span / 4.0)
    if above:  # mean < low: a one-sided bound above it (low only)
        low = mean + gap
        bounds, name = f"low = {low!r}", "low"
    else:  # mean > high
        high = mean - gap
        bounds, name = f"high = {high!r}", "high"
    assume_inside = lo <= mean - gap and mean + gap <= hi
    if not assume_inside:
        return
    given_mean = f"mean = {mean!r}, " if with_mean else ""
    text = _file(table, key, f"{{ dist = 'normal', {given_mean}sigma = {sigma!r}, {bounds} }}")
    with pytest.raises(ConfigError) as info:
        parse_dispersions(text, SCENARIO, "f.toml")
    assert info.value.where == f"f.toml: {table}.{key}.{name}", info.value
    assert "clip bounds" in info.value.detail


@QUICK
@given(target=st.sampled_from(TARGETS), width=st.floats(1e-3, 1.0), ratio=st.floats(1.01, 1e6))
def test_a_normal_wider_than_its_own_clip_bounds_is_refused(target, width, ratio):
    """σ = ratio × (high − low) about a mean in the middle: most draws on the two ends; refused at
    ``KEY.sigma``."""
    table, key, nominal, (lo, hi) = target
    centre = nominal if lo < nominal - width and nominal + width < hi else (lo + hi) / 2.0
    sigma = min(ratio * 2 * width, (hi - lo) / 2.0)
    if not sigma > 2 * width:
        return
    text = _file(
        table, key,
        f"{{ dist = 'normal', mean = {centre!r}, sigma = {sigma!r}, "
        f"low = {centre - width!r}, high = {centre + width!r} }}",
    )  # fmt: skip
    with pytest.raises(ConfigError) as info:
        parse_dispersions(text, SCENARIO, "f.toml")
    assert info.value.where == f"f.toml: {table}.{key}.sigma", info.value


@pytest.mark.parametrize("target", TARGETS, ids=lambda t: f"{t[0]}.{t[1]}")
def test_a_normal_within_its_clip_bounds_still_disperses(target):
    """A mean inside the bounds and σ within them: the draws vary and stay within them."""
    table, key, nominal, (lo, hi) = target
    mean = 3.0 if table.startswith("faults.") else nominal
    text = _file(table, key, f"{{ dist = 'normal', mean = {mean!r}, sigma = 1.0, low = {mean - 1.5!r}, "
                             f"high = {mean + 2.0!r} }}")  # fmt: skip
    values = _column_draws(text, key)
    assert values.size and np.ptp(values) > 0, values
    floor = max(mean - 1.5, 1e-3 if key == "duration_s" else -np.inf)
    assert np.all(values >= floor - 0.5) and np.all(values <= mean + 2.0 + 0.5)


def test_hil_montecarlo_refuses_a_clip_bound_far_from_its_mean_before_any_run(tmp_path):
    """Through the command: the 100 σ truncated inertia is refused naming the file and key, status 2, no
    campaign directory made (a campaign that dispersed nothing)."""
    disp = tmp_path / "far.toml"
    disp.write_text("[spacecraft]\ninertia_scale = { dist = 'normal', sigma = 0.01, low = 2.0 }\n")
    out = tmp_path / "campaign"
    proc = subprocess.run(
        [sys.executable, "-m", "hil", "montecarlo", "cubesat-1u", "--dispersions", str(disp), "--runs", "2",
         "--workers", "1", "--out", str(out), "--no-plots"],
        capture_output=True, text=True, timeout=240,
    )  # fmt: skip
    assert proc.returncode == 2, proc.stderr
    assert "far.toml: spacecraft.inertia_scale.low" in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr, proc.stderr
    assert not out.exists()


@QUICK
@given(
    where=st.sampled_from(["link", "stall", "phone_gap", "noise"]),
    others=st.lists(st.floats(1e-3, 60.0), max_size=4),
    zero=st.sampled_from([0.0, -0.0]),
    as_normal=st.booleans(),
)
def test_a_duration_of_zero_in_a_choice_or_a_normal_of_no_spread_is_refused(where, others, zero, as_normal):
    """Any value of 0 s as written (among a choice's values; for a fault, a normal of σ 0 about 0 too) is
    refused naming the key, not flown as a 1 ms fault or outage."""
    if as_normal and where != "link":  # a link outage's normal is clipped into 1 ms..60 s as its tail is
        dist = f"{{ dist = 'normal', mean = {zero!r}, sigma = 0.0 }}"
    else:
        values = [*others, zero]
        dist = f"{{ dist = 'choice', values = [{', '.join(repr(v) for v in values)}] }}"
    if where == "link":
        text = f"[link]\noutages_per_minute = 6.0\noutage_duration_s = {dist}\n"
        at = "f.toml: link.outage_duration_s"
    else:
        extra = ", corrupt = 0.1" if where == "noise" else ""
        text = f"[faults]\n{where} = {{ count = 2, duration_s = {dist}{extra} }}\n"
        at = f"f.toml: faults.{where}.duration_s"
    with pytest.raises(ConfigError) as info:
        parse_dispersions(text, SCENARIO, "f.toml")
    assert info.value.where == at, info.value
    assert "positive" in info.value.detail


def test_a_slew_dispersed_past_half_a_turn_is_refused_as_the_scenario_refuses_it(tmp_path):
    """The scenario refuses a slew beyond ±180° (flown the short way, 270° is 90° about the opposite axis);
    a campaign's ``manoeuvre.angle_deg`` took ±360°, flew a drawn 270° as 90° back and recorded 270."""
    from hil.montecarlo.dispersions import parse_dispersions
    from hil.scenario import load_scenario
    from protocol.errors import ConfigError

    scenario = load_scenario()
    for text in (
        "manoeuvre.angle_deg = 270.0",
        'manoeuvre.angle_deg = { dist = "uniform", low = 0, high = 270 }',
    ):
        with pytest.raises(ConfigError, match="manoeuvre.angle_deg"):
            parse_dispersions(text, scenario, "d.toml")
    parse_dispersions(
        'manoeuvre.angle_deg = { dist = "uniform", low = -180, high = 180 }', scenario, "d.toml"
    )
