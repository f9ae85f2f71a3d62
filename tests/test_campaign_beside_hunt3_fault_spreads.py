"""A fault campaign's ``relative_sigma``: a spread of nothing, or wider than the whole range.

A ``[faults]`` kind's count and parameters have no nominal value of their own (a draw is handed 0), so
``count = { dist = "normal", relative_sigma = 0.5 }`` was σ = 0.5 × 0: every run drew 0 faults of the
kind — a fault campaign that injected nothing and said every run kept its invariants — and a
``duration_s`` so dispersed made every stall the shortest, 1 ms. ``mean = 3, relative_sigma = 1e300``
passed the "wider than the whole range" check that ``sigma`` gets, and every run drew 0 or 100 hangs. Both
are now refused as the file is read, naming the file and the key (as dispersions' ``relative_sigma`` is).
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.montecarlo.dispersions import draw, parse_dispersions
from hil.montecarlo.fault_plan import MAX_COUNT, MAX_DURATION_S
from hil.scenario import load_scenario
from protocol.errors import ConfigError

SCENARIO = load_scenario("cubesat-1u")

# (kind, key, range): a kind's count, and one of its number parameters, as fault_plan bounds them
TARGETS = [
    ("hang", "count", (0.0, float(MAX_COUNT))),
    ("stall", "duration_s", (0.0, MAX_DURATION_S)),
    ("phone_gap", "duration_s", (0.0, MAX_DURATION_S)),
    ("noise", "corrupt", (0.0, 1.0)),
    ("phone_jump", "offset_s", (-86_400.0, 86_400.0)),
]
REQUIRED = {"stall": {"duration_s": "1.0"}, "phone_gap": {"duration_s": "1.0"},
            "phone_jump": {"offset_s": "2.0"}, "noise": {"duration_s": "1.0", "corrupt": "0.1"}}  # fmt: skip


def _file(kind: str, key: str, dist: str) -> str:
    """A dispersion file of one fault kind: two of it, its required parameters, and ``key`` = ``dist``."""
    params = {"count": "2", **REQUIRED.get(kind, {}), key: dist}
    return f"[faults]\n{kind} = {{ {', '.join(f'{k} = {v}' for k, v in params.items())} }}\n"


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    target=st.sampled_from(TARGETS),
    relative=st.floats(1e-6, 1e308, allow_nan=False),
    with_zero_mean=st.booleans(),
)
def test_relative_sigma_of_a_fault_about_no_mean_is_refused_naming_the_key(target, relative, with_zero_mean):
    kind, key, _ = target
    mean = ", mean = 0" if with_zero_mean else ""
    text = _file(kind, key, f"{{ dist = 'normal', relative_sigma = {relative!r}{mean} }}")
    try:
        parse_dispersions(text, SCENARIO, "f.toml")
    except ConfigError as exc:
        assert exc.where == f"f.toml: faults.{kind}.{key}.relative_sigma", exc
        assert "no run would be dispersed" in exc.detail
    else:
        raise AssertionError(f"taken: every run's {kind} {key} would be drawn from σ = 0\n{text}")


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(target=st.sampled_from(TARGETS), fraction=st.floats(0.0, 1.0), relative=st.floats(1e-3, 1e308))
def test_relative_sigma_of_a_fault_is_refused_wider_than_its_range_and_disperses_within_it(
    target, fraction, relative
):
    kind, key, (lo, hi) = target
    mean = lo + fraction * (hi - lo)
    if mean == 0.0 or (key == "duration_s" and mean <= 0.0):
        mean = hi / 2
    text = _file(kind, key, f"{{ dist = 'normal', mean = {mean!r}, relative_sigma = {relative!r} }}")
    spread = relative * abs(mean)
    try:
        d = parse_dispersions(text, SCENARIO, "f.toml")
    except ConfigError as exc:
        assert not spread <= hi - lo, f"a spread of {spread:g} within {lo:g}..{hi:g} refused: {exc}"
        assert exc.where == f"f.toml: faults.{kind}.{key}.relative_sigma", exc
        return
    assert spread <= hi - lo, f"a spread of {spread:g}, wider than {lo:g}..{hi:g}, taken:\n{text}"
    assert d.faults is not None
    for index in range(3):  # within the kind's range, whatever the tail
        for fault in draw(d, 2, index).faults or ():
            for value in fault.params.values():
                if isinstance(value, float):
                    assert np.isfinite(value)


def test_hil_montecarlo_refuses_a_fault_count_of_no_spread_before_any_run(tmp_path):
    """Through the command: status 2, the file and the key on stderr, no campaign directory made."""
    bad = tmp_path / "none.toml"
    bad.write_text("[faults]\nhang = { count = { dist = 'normal', relative_sigma = 0.5 } }\n")
    out = tmp_path / "mc"
    done = subprocess.run(
        [sys.executable, "-m", "hil", "montecarlo", "cubesat-1u", "--dispersions", str(bad), "--runs", "2",
         "--workers", "1", "--out", str(out), "--no-plots"],
        capture_output=True, text=True, timeout=240,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    assert "none.toml: faults.hang.count.relative_sigma" in done.stderr, done.stderr
    assert "Traceback" not in done.stderr
    assert not out.exists()
