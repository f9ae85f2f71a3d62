"""A campaign resumed by other code: the runs of two versions pooled in one summary.

A campaign's workers were held to its driver's code (a worker running other code refuses its chunk: "a
campaign never mixes results of two versions"), but campaign.json did not record the code, and a resume
never compared it: ``hil montecarlo ... --runs 1000 --out mc/c1`` after ``pip install -U`` (or a commit)
ran the 800 new runs with the new code beside the 200 old ones and summarised all 1000 as one campaign,
unsaid. campaign.json now records ``code`` (:func:`hil.version.describe`) and a resume by other code is a
ConfigError naming campaign.json (status 2, nothing run); a manifest written before the record was kept
is taken as it was, and one whose record is damaged is refused, never a traceback.
"""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from montecarlo_support import write_quick_scenario

from hil import version
from hil.montecarlo import Campaign, parse_dispersions
from hil.montecarlo.store import MANIFEST, RUNS, ResultStore
from hil.scenario import load_scenario
from protocol.errors import ConfigError

INERTIA = "[spacecraft]\ninertia_scale = { dist = 'normal', mean = 1.0, sigma = 0.05 }\n"


def _montecarlo(scenario: Path, out: Path, runs: int) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "hil", "montecarlo", str(scenario), "--runs", str(runs), "--workers", "1",
         "--out", str(out), "--no-plots"],
        capture_output=True, text=True, timeout=280,
    )  # fmt: skip


def _rows(out: Path) -> list[str]:
    with open(out / RUNS, newline="") as f:
        return [row[0] for row in list(csv.reader(f))[1:]]


REMOVED = object()
"""campaign.json without its ``code`` (as written before it was recorded)."""


def _set_code(out: Path, code: object) -> None:
    info = json.loads((out / MANIFEST).read_text())
    if code is REMOVED:
        info.pop("code", None)
    else:
        info["code"] = code
    (out / MANIFEST).write_text(json.dumps(info, indent=2) + "\n")


def test_a_campaign_made_by_other_code_is_not_extended_by_this_code(tmp_path):
    """Through the command: a campaign of one run, its campaign.json saying another release made it (as
    an older install's would), is refused when asked for more runs — status 2, campaign.json named, no
    run added — and extended once it says this code made it."""
    scenario = write_quick_scenario(tmp_path)
    out = tmp_path / "mc"
    first = _montecarlo(scenario, out, 1)
    assert first.returncode == 0, first.stderr
    recorded = json.loads((out / MANIFEST).read_text()).get("code")
    assert recorded == version.describe(), "campaign.json does not say which code ran the campaign"

    _set_code(out, {"version": "0.0.1", "revision": "0123abc"})
    other = _montecarlo(scenario, out, 2)
    assert other.returncode == 2, f"extended by other code:\n{other.stderr}"
    assert str(out / MANIFEST) in other.stderr and "other code" in other.stderr, other.stderr
    assert "Traceback" not in other.stderr
    assert _rows(out) == ["0"], "a run was added to another code's campaign"

    _set_code(out, recorded)
    same = _montecarlo(scenario, out, 2)
    assert same.returncode == 0, same.stderr
    assert sorted(_rows(out)) == ["0", "1"]


@pytest.fixture(scope="module")
def campaign(tmp_path_factory):
    scenario = load_scenario(write_quick_scenario(tmp_path_factory.mktemp("sc")))
    return Campaign(scenario, parse_dispersions(INERTIA, scenario, "inertia.toml"), runs=2, seed=1)


def test_a_manifest_written_before_the_code_was_recorded_is_resumed(tmp_path, campaign):
    out = tmp_path / "mc"
    ResultStore(out, campaign.manifest()).close()
    _set_code(out, REMOVED)
    with ResultStore(out, campaign.manifest()) as store:
        assert store.finished == set()


_TEXT = st.one_of(st.none(), st.text(max_size=12), st.integers(), st.floats(allow_nan=True), st.booleans())


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    record=st.one_of(
        _TEXT,
        st.lists(_TEXT, max_size=3),
        st.dictionaries(st.sampled_from(["version", "revision", "other"]), _TEXT, max_size=3),
    )
)
def test_any_code_record_resumes_only_when_it_is_this_code(tmp_path_factory, campaign, record):
    """Whatever campaign.json's ``code`` holds, a session either resumes it (this code's record) or is a
    ConfigError naming campaign.json — never a traceback, never a resume under another version."""
    out = tmp_path_factory.mktemp("mc")
    ResultStore(out, campaign.manifest()).close()
    _set_code(out, record)
    this = version.describe()
    try:
        ResultStore(out, campaign.manifest()).close()
    except ConfigError as exc:
        assert exc.where == str(out / MANIFEST), exc
        assert "code" in exc.detail
        return
    assert isinstance(record, dict) and version.mismatch(this, record) is None, record
