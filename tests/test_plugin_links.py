"""A user's phone source or transport that misbehaves mid-run — returns what is not a list of
SensorSamples, not bytes, or raises its own exception, in its factory or mid-run — ends ``hil run`` with a
PluginError naming it, what it did and when: exit status 2, one line, no traceback, the summary says
error (never completed), and a phone source's board is left disarmed. Before, each was a raw traceback
(``AttributeError: 'tuple' object has no attribute 't_s'`` from the host, ``TypeError: must be str, not
int`` from the deframer). Samples of the right types that are out of order or repeated are the host's
admission's to count, the run going on."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from plugin_support import still_samples

from hil.cli import main
from hil.estimation.sensors import SensorKind, SensorSample
from hil.link import sources, transports
from hil.link.sources import PhoneSource
from hil.link.sources.checked import CheckedSource
from hil.link.transports.base import Transport
from hil.link.transports.checked import CheckedTransport
from hil.plugins import PluginError

MODULE = "misbehaving_links_for_test"
ROOT = Path(__file__).resolve().parents[1]


def _options(url: str) -> tuple[str, int]:
    query = {k: v[0] for k, v in parse_qs(urlsplit(url).query).items()}
    return query.get("mode", "ok"), int(query.get("after", "50"))


class Still(PhoneSource):
    """A phone lying still (gyro 0, gravity, a field) at 200 Hz of the run's clock, until its ``after``-th
    drain: then what ``mode`` says."""

    def __init__(self, url, context) -> None:
        self.url = url
        self.mode, self.after = _options(url)
        self.next_t = None
        self.n = 0
        self.previous: list = []

    def drain(self, now):
        self.n += 1
        out, self.next_t = still_samples(now if self.next_t is None else self.next_t, now)
        previous, self.previous = self.previous, out
        if self.n < self.after:
            return out
        if self.mode == "raises":
            raise RuntimeError("my rig fell over")
        if self.mode == "tuples":
            return [(s.t_s, s.kind, s.xyz) for s in out]
        if self.mode == "none":
            return None
        if self.mode == "text_stamps":
            return [SensorSample(str(s.t_s), s.kind, s.xyz) for s in out]
        if self.mode == "again":  # the last batch again, then this one twice, backwards
            return previous + out + out[::-1]
        return out

    def truth(self, now):
        if self.mode == "scaled_truth" and self.n >= self.after:
            return type("Truth", (), {"R": 2.0 * np.eye(3), "omega": np.zeros(3)})()
        return None

    def report(self):
        return {"phone": {"rig": object()}} if self.mode == "report" else {}

    def close(self) -> None:
        """Nothing to release (the readings are made up on demand), unless the URL says ``close=raises``."""
        if "close=raises" in self.url:
            raise OSError("the rig's socket would not close")


def broken_rig(url, context):
    raise KeyError("no such rig")


class Faulty(Transport):
    """The in-process emulator on the wall clock behind a plugin's transport, until its ``after``-th read:
    then what ``mode`` says."""

    def __init__(self, url: str) -> None:
        super().__init__(url)
        from hil.timing.clock import WallClock

        self.mode, self.after = _options(url)
        self.inner = transports.create_transport("emu://?units=4")
        self.inner.bind_clock(WallClock())
        self.n = 0

    def _open_impl(self) -> None:
        if self.mode == "open_raises":
            raise RuntimeError("bus adapter on fire")
        self.inner.open()

    def _read(self, timeout):
        self.n += 1
        data = self.inner.read(timeout)
        if self.n < self.after:
            return data
        if self.mode == "raises":
            raise RuntimeError("the adapter went away my way")
        if self.mode == "text":
            return data.decode("latin-1")
        return data

    def _write(self, data) -> None:
        self.inner.write(data)

    def _close(self) -> None:
        self.inner.close()


def broken_bus(url):
    raise ZeroDivisionError("in my factory")


@pytest.fixture(autouse=True)
def _registered() -> Iterator[None]:
    module = type(sys)(MODULE)
    module.Still, module.broken_rig, module.Faulty, module.broken_bus = Still, broken_rig, Faulty, broken_bus  # type: ignore[attr-defined]
    sys.modules[MODULE] = module
    sources.register("still", f"{MODULE}:Still")
    sources.register("brokenrig", f"{MODULE}:broken_rig")
    transports.register("faulty", f"{MODULE}:Faulty")
    transports.register("brokenbus", f"{MODULE}:broken_bus")
    try:
        yield
    finally:
        del sys.modules[MODULE]


def _run(tmp_path, capsys, port: str, phone: str, duration: str = "3") -> tuple[int, dict, str]:
    args = ["run", "--port", port, "--phone", phone, "--duration", duration, "--no-plots"]
    code = main([*args, "--out", str(tmp_path)])
    err = capsys.readouterr().err
    (run_dir,) = tmp_path.iterdir()
    return code, json.loads((run_dir / "summary.json").read_text()), err


@pytest.mark.parametrize(
    ("mode", "said"),
    [
        ("raises", "drain at t = .* s raised RuntimeError: my rig fell over"),
        ("tuples", r"drain at t = .* s returned, at \[0\] of \d+, tuple .*, not a SensorSample"),
        ("none", "drain at t = .* s returned NoneType None, not a list of SensorSamples"),
        ("text_stamps", "drain at t = .* s returned, at .* a sample stamped str .*, not a number of seconds"),
        ("scaled_truth", "truth at t = .* s returned an attitude that is not a rotation"),
    ],
)
def test_a_phone_source_that_misbehaves_ends_the_run_in_error_with_the_board_disarmed(
    mode, said, tmp_path, capsys
):
    code, summary, err = _run(tmp_path, capsys, "emu://", f"still://desk?mode={mode}")
    assert code == 2, summary["exit"]
    assert summary["exit"].startswith("error: phone source 'still': ")
    import re

    assert re.search(said, summary["exit"]), summary["exit"]
    assert summary["final_disarm"]["state"] == "DISARMED" and summary["final_disarm"]["ok"]
    lines = [line for line in err.splitlines() if "phone source 'still'" in line]
    assert len(lines) == 1 and lines[0].startswith("hil run: phone source 'still': ")
    assert "Traceback" not in err


def test_a_close_that_fails_after_the_run_failed_is_said_not_made_the_runs_error(tmp_path, capsys):
    """The drain's fault ends the run; the close that then fails too is said in events.jsonl, and the exit
    still names the drain (it named the close, the drain's fault lost)."""
    code, summary, err = _run(tmp_path, capsys, "emu://", "still://desk?mode=raises&close=raises")
    assert code == 2 and "Traceback" not in err
    assert summary["exit"].startswith("error: phone source 'still': drain at t = "), summary["exit"]
    (run_dir,) = tmp_path.iterdir()
    events = [json.loads(line) for line in (run_dir / "events.jsonl").read_text().splitlines()]
    (failed,) = [e for e in events if e["kind"] == "close_failed"]
    assert failed["what"] == "the phone source" and "would not close" in failed["error"]
    assert summary["final_disarm"]["state"] == "DISARMED" and summary["final_disarm"]["ok"]


def test_a_close_that_fails_after_a_run_that_went_well_is_the_runs_error(tmp_path, capsys):
    code, summary, err = _run(tmp_path, capsys, "emu://", "still://desk?close=raises", "1")
    assert code == 2 and "Traceback" not in err
    assert (
        summary["exit"]
        == "error: phone source 'still': close raised OSError: the rig's socket would not close"
    )


def test_a_phone_source_factory_that_raises_is_named(tmp_path, capsys):
    code, summary, err = _run(tmp_path, capsys, "emu://", "brokenrig://desk")
    assert code == 2 and "Traceback" not in err
    said = f"phone source 'brokenrig': its factory {MODULE}:broken_rig raised KeyError: 'no such rig'"
    assert summary["exit"] == f"error: {said}" and f"hil run: {said}" in err
    assert summary["final_disarm"]["state"] == "DISARMED"


def test_a_report_summary_json_cannot_hold_makes_the_run_an_error_with_its_summary_written(tmp_path, capsys):
    code, summary, err = _run(tmp_path, capsys, "emu://", "still://desk?mode=report", "1")
    assert code == 2 and "Traceback" not in err
    assert summary["exit"].startswith("error: phone source 'still': report returned what summary.json")
    assert summary["final_disarm"]["state"] == "DISARMED" and summary["final_disarm"]["ok"]


def test_out_of_order_and_repeated_samples_are_counted_drops_not_a_crash(tmp_path, capsys):
    code, summary, err = _run(tmp_path, capsys, "emu://", "still://desk?mode=again&after=1", "1")
    assert code == 0 and summary["exit"] == "completed", summary["exit"]
    dropped = summary["phone_admission"]["dropped"]
    assert dropped["duplicate"] > 100 and dropped["out_of_order"] > 10, dropped
    assert summary["phone_admission"]["accepted"] > 500


@pytest.mark.parametrize(
    ("mode", "said"),
    [
        ("raises", r"read #200 \(after \d+ bytes in\) raised RuntimeError: the adapter went away my way"),
        ("text", r"read #200 \(after \d+ bytes in\) returned str .*, not bytes"),
        ("open_raises", "open of faulty://.* raised RuntimeError: bus adapter on fire"),
    ],
)
def test_a_transport_that_misbehaves_ends_the_run_in_error_naming_it(mode, said, tmp_path, capsys):
    code, summary, err = _run(tmp_path, capsys, f"faulty://?mode={mode}&after=200", "still://desk")
    assert code == 2, summary["exit"]
    import re

    assert re.fullmatch(f"error: transport 'faulty': {said}", summary["exit"]), summary["exit"]
    lines = [line for line in err.splitlines() if "transport 'faulty'" in line]
    assert len(lines) == 1 and lines[0].startswith("hil run: transport 'faulty': ")
    assert "Traceback" not in err


def test_a_transport_factory_that_raises_is_named(tmp_path, capsys):
    code, summary, err = _run(tmp_path, capsys, "brokenbus://x", "still://desk")
    said = f"transport 'brokenbus': its factory {MODULE}:broken_bus raised ZeroDivisionError: in my factory"
    assert code == 2 and summary["exit"] == f"error: {said}" and f"hil run: {said}" in err


def test_an_installed_plugin_says_it_in_one_line_from_the_hil_process(tmp_path):
    """A package installed beside the project (a dist-info and a module on sys.path, as pip leaves them),
    run by ``python -m hil run``: one line on stderr, status 2."""
    (tmp_path / "thirdparty_rig.py").write_text(textwrap.dedent('''
        from hil.link.sources import PhoneSource

        class Rig(PhoneSource):
            def __init__(self, url, context):
                self.url = url
            def drain(self, now):
                return [("not", "a", "sample")]
            def truth(self, now):
                return None
            def close(self):
                self.url = ""  # nothing else to release
    '''))  # fmt: skip
    info = tmp_path / "thirdparty_rig-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: thirdparty-rig\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[vscmg_hil.phone_sources]\nrig = thirdparty_rig:Rig\n")
    env = {"PYTHONPATH": f"{tmp_path}:{ROOT}", "PATH": "/usr/bin:/bin", "PYTHONDONTWRITEBYTECODE": "1"}
    args = ["run", "--port", "emu://", "--phone", "rig://desk", "--duration", "2", "--no-plots"]
    out = subprocess.run(
        [sys.executable, "-m", "hil", *args, "--out", str(tmp_path / "runs")],
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
        cwd=ROOT,
    )
    assert out.returncode == 2, out.stderr
    assert "Traceback" not in out.stderr
    (line,) = [x for x in out.stderr.splitlines() if "phone source 'rig'" in x]
    assert line.startswith("hil run: phone source 'rig': drain at t = ") and "not a SensorSample" in line


# --------------------------------------------------------------------------- the wrappers, by property
class _Drains(PhoneSource):
    def __init__(self, out) -> None:
        self.url, self.out = "mine://", out

    def drain(self, now):
        return self.out

    def truth(self, now):
        return None

    def close(self) -> None:
        """Nothing held."""


reals = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-(10**6), 10**6))
junk = st.one_of(st.none(), st.text(max_size=5), st.booleans(), st.binary(max_size=3), reals)
samples = st.builds(
    SensorSample,
    st.one_of(reals, junk),
    st.one_of(st.sampled_from(list(SensorKind)), junk),
    st.one_of(
        st.tuples(reals, reals, reals),
        st.lists(reals, min_size=3, max_size=3).map(np.array),
        st.lists(st.one_of(reals, junk), max_size=4),
        junk,
    ),
)


@settings(max_examples=300, deadline=None)
@given(st.one_of(st.lists(st.one_of(samples, junk), max_size=6), junk, st.tuples(samples)))
def test_a_drain_is_passed_on_as_samples_of_floats_or_is_a_plugin_error(out):
    checked = CheckedSource(_Drains(out), "mine")
    try:
        got = checked.drain(1.0)
    except PluginError as exc:
        assert exc.plugin == "phone source 'mine'" and "drain at t = 1.000000 s" in str(exc)
        return
    assert isinstance(got, list) and len(got) == len(out)
    for s in got:  # what the host's admission takes as it is (NaN, out of range: its own to count)
        assert type(s) is SensorSample and type(s.t_s) is float and type(s.kind) is SensorKind
        assert type(s.xyz) is tuple and len(s.xyz) == 3 and all(type(v) is float for v in s.xyz)


class _Reads(Transport):
    def __init__(self, out) -> None:
        super().__init__("mine://")
        self.out = out

    def _open_impl(self) -> None:
        """Nothing to open."""

    def _read(self, timeout):
        if isinstance(self.out, Exception):
            raise self.out
        return self.out

    def _write(self, data) -> None:
        """Swallowed."""

    def _close(self) -> None:
        """Nothing to close."""


@settings(max_examples=200, deadline=None)
@given(
    st.one_of(
        st.binary(max_size=8),
        st.binary(max_size=8).map(bytearray),
        junk,
        st.lists(st.integers(0, 255), max_size=3),
        st.sampled_from([ValueError("x"), OSError("y"), KeyError("z")]),
    )
)
def test_a_read_is_passed_on_as_bytes_or_is_a_plugin_error(out):
    link = CheckedTransport(_Reads(out), "mine").open()
    try:
        got = link.read(0)
    except PluginError as exc:
        assert exc.plugin == "transport 'mine'" and "read #1 (after 0 bytes in)" in str(exc)
        assert not isinstance(out, (bytes, bytearray))
    else:
        assert type(got) is bytes and got == bytes(out) and link.bytes_in == len(got)
