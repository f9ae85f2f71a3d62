"""A campaign's failed run whose error is long, or holds characters UTF-8 cannot (a hunt; real runs, the
campaign's own store and reader, ``hil report`` on the files).

A user's estimator that raised with a message of 2 MB (an array quoted, a file read into it) failed its run
as it should, but its row in runs.csv was longer than the reader's longest line: read back it was dropped
as damaged — the summary said "1 runs, 1 ok, 0 failed" of a campaign whose run had failed, so
``hil montecarlo`` exited 0, and every later session ran the run again. A message with a lone surrogate (a
file name that is not UTF-8) ended the session in a ``UnicodeEncodeError`` traceback. Now a message is
kept to :data:`~hil.montecarlo.store.MAX_MESSAGE_CHARS`, the cut said, and written as UTF-8 (what it
cannot hold escaped): every failed run is in the summary, with its error.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from montecarlo_support import write_quick_scenario
from plugin_support import Delegating, estimators_in_a_module

from hil.cli import main
from hil.estimation.variational_kind import VARIATIONAL
from hil.montecarlo import Campaign, parse_dispersions, read_runs
from hil.montecarlo.campaign import summarise_dir
from hil.montecarlo.metrics import METRICS, TRACES, trace_length
from hil.montecarlo.runner import RunResult, run_chunk
from hil.montecarlo.store import MAX_MESSAGE_CHARS, ResultStore
from hil.scenario import load_scenario

INERTIA = '[spacecraft]\ninertia_scale = { dist = "normal", sigma = 0.05 }\n'
MODULE = "long_errors_for_test"
HUGE = 2_000_000


class Loud(Delegating):
    """The variational estimator, raising from its 50th step on with a message of :data:`HUGE` characters."""

    def __init__(self, inner) -> None:
        super().__init__(inner)
        self.n = 0

    def step(self, s):
        self.n += 1
        if self.n > 50:
            raise ValueError("x" * HUGE)
        return self.inner.step(s)


class Kind:
    keys = frozenset({"preset"})

    def check(self, settings, where):
        return VARIATIONAL.check(settings, where)

    def build(self, settings, site):
        return Loud(VARIATIONAL.build(settings, site))

    def describe(self, settings):
        return "the variational estimator, raising at length"


@pytest.fixture(scope="module")
def scenario(tmp_path_factory):
    return load_scenario(write_quick_scenario(tmp_path_factory.mktemp("scenario")))


def _campaign(scenario, runs: int) -> Campaign:
    return Campaign(scenario, parse_dispersions(INERTIA, scenario, "inertia.toml"), runs=runs, seed=1)


def test_a_run_failing_with_a_message_of_megabytes_is_a_failed_run_in_the_summary(tmp_path, capsys):
    """A real run whose (user's) estimator raises with 2 MB of message, and a real ok run beside it: the
    summary says 2 runs, 1 ok, 1 failed, with the error's start (it said 1 runs, 1 ok, 0 failed)."""
    with estimators_in_a_module(MODULE, {"loud": ("LOUD", Kind())}):  # hil report rebuilds it too
        path = write_quick_scenario(tmp_path)
        text = path.read_text().replace("[estimator]\n", '[estimator]\nkind = "loud"\n')
        assert 'kind = "loud"' in text
        loud = tmp_path / "loud.toml"
        loud.write_text(text)
        loud_scenario = load_scenario(loud)
        campaign = _campaign(loud_scenario, 2)
        (failed,) = run_chunk(loud_scenario, [campaign.draw(0)], campaign.trace_hz)
        assert not failed.ok and failed.error.startswith("PluginError: estimator 'loud'")
        out = tmp_path / "mc"
        with ResultStore(out, campaign.manifest()) as store:
            store.append(failed)
            samples = trace_length(loud_scenario.slew.duration_s, campaign.trace_hz)
            trace = np.full((len(TRACES), samples), 0.1, dtype=np.float32)
            store.append(RunResult(1, True, campaign.draw(1).columns, dict.fromkeys(METRICS, 0.1), trace))
        summary = summarise_dir(out, loud_scenario, write=False)
        assert (summary["runs"], summary["ok"], summary["failed"], summary["dropped_lines"]) == (2, 1, 1, 0)
        (said,) = summary["failures"]
        assert said["index"] == 0 and said["error"].startswith("PluginError: estimator 'loud'")
        if len(failed.error) > MAX_MESSAGE_CHARS:  # the estimator's whole message, as the runner has it
            assert said["error"].endswith("more characters not kept]")
        capsys.readouterr()
        assert main(["report", "--no-plots", str(out)]) == 0
        assert "2 runs, 1 ok, 1 failed" in capsys.readouterr().out
    # a session resuming the directory has both runs: neither is run again
    with ResultStore(out, campaign.manifest()) as store:
        assert store.finished == {0, 1}


CHARACTER = st.one_of(st.characters(), st.characters(categories=["Cs"]))  # lone surrogates too
MESSAGE = st.builds(
    lambda piece, n: piece * n, st.text(CHARACTER, min_size=1, max_size=40), st.integers(1, 60_000)
)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(messages=st.lists(st.one_of(MESSAGE, st.text(max_size=50)), min_size=1, max_size=4))
def test_every_failed_run_is_read_back_failed_with_its_message_however_long(
    tmp_path_factory, scenario, messages
):
    """Failed runs whose errors are drawn — any characters (lone surrogates, ``\\r``, unicode), up to
    megabytes — are each read back failed, with their message's start, none dropped."""
    campaign = _campaign(scenario, len(messages))
    out = tmp_path_factory.mktemp("long") / "mc"
    with ResultStore(out, campaign.manifest()) as store:
        for i, message in enumerate(messages):
            store.append(RunResult.failed(campaign.draw(i), ValueError(message)))
    results = read_runs(out)
    assert results.dropped == 0 and results.index.tolist() == list(range(len(messages)))
    assert not results.ok.any()
    for i, message in enumerate(messages):
        kept = results.errors[i]
        assert kept.startswith("ValueError: ")
        if len(message) + len("ValueError: ") <= MAX_MESSAGE_CHARS and message.isprintable():
            assert kept == f"ValueError: {message}".replace("\n", " | ")
        assert len(kept) <= 8 * MAX_MESSAGE_CHARS  # bounded: escaped characters take up to 10 each


@pytest.mark.parametrize("message", ["board said: ERR\r\nreset\r\n", "frame 00 00\x00\x00 raw", "a\rb"])
def test_an_error_quoting_a_devices_line_breaks_or_nul_is_read_back_with_its_run(tmp_path, scenario, message):
    """A carriage return or a NUL in an error (a device's banner quoted) made csv refuse the row read back:
    the failed run was dropped as damaged. It is read back failed, the break shown as `` | ``."""
    campaign = _campaign(scenario, 1)
    with ResultStore(tmp_path / "mc", campaign.manifest()) as store:
        store.append(RunResult.failed(campaign.draw(0), ValueError(message)))
    results = read_runs(tmp_path / "mc")
    assert results.dropped == 0 and results.index.tolist() == [0] and not results.ok.any()
    kept = results.errors[0]
    assert "\r" not in kept and "\x00" not in kept
    assert kept.startswith("ValueError: ") and (" | " in kept or "\\x00" in kept)
