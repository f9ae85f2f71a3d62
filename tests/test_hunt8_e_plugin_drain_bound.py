"""A user's phone source whose ``drain`` hands over an unbounded batch — a million readings in one call, at
a drawn drain of the run — is its :class:`PluginError`, naming it and the call, in a real ``hil run``
(exit status 2, one line, the board disarmed); a batch up to the bound is passed on.

Before: the batch was checked sample by sample, copied, sorted and fed on the control thread, however
large: memory and a stalled control loop without bound, drain after drain, and the run went on."""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator
from urllib.parse import parse_qs, urlsplit

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from plugin_support import still_samples

from hil.cli import main
from hil.estimation.sensors import SensorKind, SensorSample
from hil.link import sources
from hil.link.sources import PhoneSource
from hil.link.sources.checked import MAX_DRAIN, CheckedSource
from hil.plugins import PluginError

MODULE = "drain_flood_for_test"
STILL = SensorSample(1.0, SensorKind.GYR, (0.0, 0.0, 0.0))


class Flooding(PhoneSource):
    """A phone lying still at 200 Hz whose drain number ``at`` (its URL's query) hands over ``n`` more
    readings at once, as a list or a tuple (``tuple=1``)."""

    def __init__(self, url, context) -> None:
        self.url, self.next_t, self.calls = url, None, 0
        q = {k: v[0] for k, v in parse_qs(urlsplit(url).query).items()}
        self.at, self.n, self.as_tuple = int(q["at"]), int(q["n"]), q.get("tuple") == "1"

    def drain(self, now):
        self.calls += 1
        out, self.next_t = still_samples(now if self.next_t is None else self.next_t, now)
        if self.calls == self.at:
            out += [SensorSample(now, SensorKind.GYR, (0.0, 0.0, 0.0))] * self.n
        return tuple(out) if self.as_tuple else out

    def truth(self, now):
        return None

    def close(self) -> None:
        """Nothing to release."""


@pytest.fixture(autouse=True)
def _registered() -> Iterator[None]:
    module = type(sys)(MODULE)
    module.Flooding = Flooding  # type: ignore[attr-defined]
    sys.modules[MODULE] = module
    sources.register("flooding", f"{MODULE}:Flooding")
    try:
        yield
    finally:
        del sys.modules[MODULE]


@settings(max_examples=4, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    at=st.integers(1, 400),
    n=st.sampled_from([MAX_DRAIN + 1, 3 * MAX_DRAIN, 1_000_000]),
    as_tuple=st.booleans(),
)
def test_a_drain_of_millions_ends_the_run_in_error_naming_the_source(at, n, as_tuple, tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    phone = f"flooding://desk?at={at}&n={n}&tuple={int(as_tuple)}"
    code = main(
        ["run", "--port", "emu://", "--phone", phone, "--duration", "3", "--no-plots", "--out", str(out)]
    )
    (run_dir,) = out.iterdir()
    summary = json.loads((run_dir / "summary.json").read_text())
    assert code == 2, summary["exit"]
    assert summary["exit"].startswith("error: phone source 'flooding': drain at t = "), summary["exit"]
    assert f"samples, more than {MAX_DRAIN} in one call" in summary["exit"], summary["exit"]
    assert summary["final_disarm"]["state"] == "DISARMED" and summary["final_disarm"]["ok"], summary


@settings(max_examples=30, deadline=None)
@given(n=st.integers(0, 2 * MAX_DRAIN), as_tuple=st.booleans())
def test_a_batch_is_passed_on_whole_up_to_the_bound_and_refused_beyond(n, as_tuple):
    inner = Flooding("flooding://desk?at=0&n=0", None)
    inner.drain = lambda now: (STILL,) * n if as_tuple else [STILL] * n  # type: ignore[method-assign]
    source = CheckedSource(inner, "flooding")
    try:
        got = source.drain(2.0)
    except PluginError as exc:
        assert n > MAX_DRAIN and f"returned {n} samples, more than {MAX_DRAIN}" in str(exc)
    else:
        assert n <= MAX_DRAIN and len(got) == n and type(got) is list
