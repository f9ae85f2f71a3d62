"""A user's plugin that gets past the wrappers' ``except Exception`` or past what they checked, in real
``hil run``s in lockstep with the plugin registered: each ends with a one-line error naming the plugin and
the call, exit status 2, ``summary.json`` written and saying so, the board disarmed where the link allows.

Before: a ``sys.exit()`` in a phone source, an estimator, a transport or a plugin's module ended ``hil``
with the plugin's own status (0 for ``sys.exit()``) and no word; a phone source's ``report()`` section
named ``source`` crashed the run's ending (no summary.json), one named ``final_disarm`` replaced the host's
own record, one 100 000 levels deep raised RecursionError; sender events with a ``t`` field, or that were
no events, and a transport's ``counters()`` that raised, were tracebacks; an estimate of 1000 rad/s was
steered on to "completed", one whose attribute raised was a traceback, a kind's ``check`` that returned
None a TypeError; a scheme with a ``_`` was listed as known and never reached."""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator
from urllib.parse import parse_qs, urlsplit

import numpy as np
import pytest
from plugin_support import Delegating, still_samples

from hil.cli import main
from hil.estimation.estimator import Estimate
from hil.estimation.registry import register_estimator
from hil.estimation.variational_kind import VARIATIONAL
from hil.link import sources, transports
from hil.link.sources import PhoneSource, SenderEvent, SenderStatus
from hil.link.transports.base import Transport

MODULE = "plugins_beside_escapes_for_test"


def _query(url: str) -> dict[str, str]:
    return {k: v[0] for k, v in parse_qs(urlsplit(url).query).items()}


class Rig(PhoneSource):
    """A phone lying still at 200 Hz of the run's clock; from its 50th drain on, what its URL says."""

    def __init__(self, url, context) -> None:
        self.url, self.q, self.next_t, self.n = url, _query(url), None, 0

    def drain(self, now):
        self.n += 1
        if self.n >= 50 and self.q.get("drain") == "exit":
            sys.exit()  # a library written as a script: status 0, no message
        out, self.next_t = still_samples(now if self.next_t is None else self.next_t, now)
        return out

    def truth(self, now):
        return None

    def senders(self):
        events = {
            "t_field": (SenderEvent("phone_other", {"t": 1.0, "sender": "10.0.0.9:5000"}),),
            "text": ("another phone",),
            "no_fields": (SenderEvent("phone_other", None),),
        }.get(self.q.get("senders", ""))
        return None if events is None else SenderStatus(events=events)

    def report(self):
        deep: dict = {}
        node = deep
        for _ in range(100_000):
            node["a"] = node = {}
        return {
            "source": {"source": {"rig": "mine"}},  # a string-valued key of the run's
            "final_disarm": {"final_disarm": {"state": "FORGED", "ok": True}},  # the host's safety record
            "deep": {"rig": {"tree": deep}},
            "own": {"rig": {"frames": np.int64(3)}},  # a section of its own
        }.get(self.q.get("report", ""), {})

    def close(self) -> None:
        """Nothing to release."""


class Relay(Transport):
    """The in-process emulator on the wall clock behind a plugin's transport; from its 200th read on, or
    at ``counters()``, what its URL says."""

    def __init__(self, url: str) -> None:
        super().__init__(url)
        from hil.timing.clock import WallClock

        self.q = _query(url)
        self.inner = transports.create_transport("emu://?units=4")
        self.inner.bind_clock(WallClock())
        self.n = 0

    def _open_impl(self) -> None:
        self.inner.open()

    def _read(self, timeout):
        self.n += 1
        if self.n >= 200 and self.q.get("read") == "exit":
            raise SystemExit(0)
        return self.inner.read(timeout)

    def _write(self, data) -> None:
        self.inner.write(data)

    def _close(self) -> None:
        self.inner.close()

    def counters(self):
        if self.q.get("counters") == "raises":
            raise RuntimeError("my adapter's counters are gone")
        if self.q.get("counters") == "int":
            return 42
        return {"adapter_frames": np.int64(self.n)}


class Steps(Delegating):
    """The variational estimator, until step 300: then what ``mode`` says."""

    def __init__(self, inner, mode: str) -> None:
        super().__init__(inner)
        self.mode, self.n = mode, 0

    def step(self, s):
        self.n += 1
        e = self.inner.step(s)
        if self.n < 300:
            return e
        if self.mode == "exit":
            sys.exit("calibration table missing")
        if self.mode == "spins":  # finite, absurd: 1000 rad/s
            return Estimate(e.t, e.R, np.array([0.0, 0.0, 1000.0]), e.omega_err, e.flags, e.iterations)
        if self.mode == "attribute_raises":
            return type("Est", (), {**{k: getattr(e, k) for k in ("t", "R", "omega", "omega_err")},
                                    "iterations": 0, "flags": property(_boom)})()  # fmt: skip
        if self.mode == "short_tuple":  # an Estimate tuple built by hand, its bytes cut short
            return tuple.__new__(Estimate, (e.t, e.flags, e.iterations, b"\0" * 8))
        return e


def _boom(self):
    raise RuntimeError("my flags are not ready")


class Kind:
    keys = frozenset({"preset"})

    def __init__(self, mode: str) -> None:
        self.mode = mode

    def check(self, settings, where):
        return None if self.mode == "check_none" else VARIATIONAL.check(settings, where)

    def build(self, settings, site):
        return Steps(VARIATIONAL.build(settings, site), self.mode)

    def describe(self, settings):
        return f"the variational estimator, then {self.mode}"


ESTIMATOR_MODES = ("exit", "spins", "attribute_raises", "short_tuple", "check_none")


@pytest.fixture(autouse=True)
def _registered() -> Iterator[None]:
    module = type(sys)(MODULE)
    module.Rig, module.Relay = Rig, Relay  # type: ignore[attr-defined]
    for mode in ESTIMATOR_MODES:
        setattr(module, mode.upper(), Kind(mode))
        register_estimator(f"steps-{mode}", f"{MODULE}:{mode.upper()}")
    sys.modules[MODULE] = module
    sources.register("rig", f"{MODULE}:Rig")
    sources.register("my_rig", f"{MODULE}:Rig")
    transports.register("relay", f"{MODULE}:Relay")
    try:
        yield
    finally:
        del sys.modules[MODULE]


def _run(tmp_path, capsys, *args: str) -> tuple[int, dict, str]:
    code = main(["run", *args, "--no-plots", "--out", str(tmp_path)])
    err = capsys.readouterr().err
    (run_dir,) = tmp_path.iterdir()
    return code, json.loads((run_dir / "summary.json").read_text()), err


def _ended_in_error(code: int, summary: dict, err: str, plugin: str, said: str) -> None:
    assert code == 2, summary["exit"]
    assert summary["exit"].startswith(f"error: {plugin}: {said}"), summary["exit"]
    lines = [line for line in err.splitlines() if plugin in line]
    assert len(lines) == 1 and lines[0] == f"hil run: {summary['exit'][len('error: ') :]}", err
    assert "Traceback" not in err


def _disarmed(summary: dict) -> None:
    assert summary["final_disarm"]["state"] == "DISARMED" and summary["final_disarm"]["ok"], summary


# --------------------------------------------------------------------------- SystemExit, anywhere
def test_a_phone_source_that_calls_sys_exit_is_named_and_the_board_disarmed(tmp_path, capsys):
    code, summary, err = _run(tmp_path, capsys, "--port", "emu://", "--phone", "rig://desk?drain=exit")
    _ended_in_error(code, summary, err, "phone source 'rig'", "drain at t = ")
    assert summary["exit"].endswith(" raised SystemExit"), summary["exit"]
    _disarmed(summary)


def test_an_estimator_that_calls_sys_exit_is_named_and_the_board_disarmed(tmp_path, capsys):
    code, summary, err = _run(tmp_path, capsys, "--estimator", "steps-exit", "--duration", "3")
    _ended_in_error(code, summary, err, "estimator 'steps-exit'", "step at t = ")
    assert summary["exit"].endswith(" raised SystemExit: calibration table missing"), summary["exit"]
    _disarmed(summary)


def test_a_transport_that_raises_system_exit_in_the_reader_thread_is_named(tmp_path, capsys):
    """The transport is dead from then on (every read exits), so the final Disarm cannot be confirmed: the
    summary says so, naming the transport, rather than "error: 0" and status 0."""
    code, summary, err = _run(
        tmp_path, capsys, "--port", "relay://x?read=exit", "--phone", "rig://desk", "--duration", "2"
    )
    _ended_in_error(code, summary, err, "transport 'relay'", r"read #200 (after ")
    assert summary["exit"].endswith(" raised SystemExit: 0"), summary["exit"]
    assert summary["final_disarm"]["sent"]


@pytest.mark.parametrize("kind", ["phone source", "transport"])
def test_a_plugin_module_that_calls_sys_exit_as_it_is_imported_is_one_line(
    kind, tmp_path, capsys, monkeypatch
):
    (tmp_path / "exits_on_import_plug.py").write_text("import sys\nsys.exit()\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "exits_on_import_plug", raising=False)
    if kind == "transport":
        transports.register("exitbus", "exits_on_import_plug:Factory")
        args = ["--port", "exitbus://x", "--phone", "rig://desk"]
    else:
        sources.register("exitrig", "exits_on_import_plug:Factory")
        args = ["--port", "emu://", "--phone", "exitrig://x"]
    code = main(["run", *args, "--duration", "1", "--no-plots", "--out", str(tmp_path / "runs")])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err
    said = "exits_on_import_plug:Factory is not available: importing exits_on_import_plug raised SystemExit"
    assert f"{kind} {said}" in err


# --------------------------------------------------------------------------- a phone source's report
@pytest.mark.parametrize(
    ("report", "said"),
    [
        ("source", "report returned 'source': a section the run writes itself"),
        ("final_disarm", "report returned 'final_disarm': a section the run writes itself"),
        ("deep", "report returned what summary.json cannot hold: ['rig']['tree']['a']['a']"),
    ],
)
def test_a_report_may_only_add_sections_of_its_own_and_the_summary_is_still_written(
    report, said, tmp_path, capsys
):
    code, summary, err = _run(
        tmp_path, capsys, "--port", "emu://", "--phone", f"rig://desk?report={report}", "--duration", "1"
    )
    _ended_in_error(code, summary, err, "phone source 'rig'", said)
    assert isinstance(summary["source"], str) and "rig" not in summary  # the run's own; none merged
    _disarmed(summary)  # the host's own record, not the plugin's "FORGED"


# --------------------------------------------------------------------------- a phone source's senders
@pytest.mark.parametrize(
    ("senders", "said"),
    [
        ("t_field", "senders returned, at events[0], a field 't': the record's own"),
        ("text", "senders returned, at events[0], str 'another phone', not a SenderEvent"),
        ("no_fields", "senders returned, at events[0], fields NoneType None, not a mapping"),
    ],
)
def test_sender_events_the_run_cannot_write_are_the_sources_error(senders, said, tmp_path, capsys):
    code, summary, err = _run(
        tmp_path, capsys, "--port", "emu://", "--phone", f"rig://desk?senders={senders}", "--duration", "1"
    )
    _ended_in_error(code, summary, err, "phone source 'rig'", said)
    _disarmed(summary)


# --------------------------------------------------------------------------- a transport's counters
@pytest.mark.parametrize(
    ("counters", "said"),
    [
        ("raises", "counters raised RuntimeError: my adapter's counters are gone"),
        ("int", "counters returned int 42, not a dict"),
    ],
)
def test_a_transports_counters_are_checked_and_the_summary_still_written(counters, said, tmp_path, capsys):
    code, summary, err = _run(
        tmp_path,
        capsys,
        "--port",
        f"relay://x?counters={counters}",
        "--phone",
        "rig://desk",
        "--duration",
        "1",
    )
    _ended_in_error(code, summary, err, "transport 'relay'", said)
    _disarmed(summary)


# --------------------------------------------------------------------------- an estimator's estimates
@pytest.mark.parametrize(
    ("mode", "said"),
    [
        (
            "spins",
            "returned omega of 1000 rad/s on an axis, beyond any spacecraft's (the gyroscope's bound, 40",
        ),
        ("attribute_raises", "reading what it returned raised RuntimeError: my flags are not ready"),
        ("short_tuple", "reading what it returned raised "),
    ],
)
def test_an_estimate_that_is_absurd_or_cannot_be_read_is_the_estimators_error(mode, said, tmp_path, capsys):
    code, summary, err = _run(tmp_path, capsys, "--estimator", f"steps-{mode}", "--duration", "3")
    _ended_in_error(code, summary, err, f"estimator 'steps-{mode}'", "step at t = ")
    assert said in summary["exit"], summary["exit"]
    _disarmed(summary)


def test_a_kinds_check_that_returns_no_settings_is_one_line_naming_it(tmp_path, capsys):
    code = main(
        ["run", "--estimator", "steps-check_none", "--duration", "1", "--no-plots", "--out", str(tmp_path)]
    )
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err
    assert "estimator 'steps-check_none': its check returned NoneType None, not the settings" in err


# --------------------------------------------------------------------------- a scheme with "_"
def test_a_phone_source_scheme_with_an_underscore_is_reached_and_a_plugins_own_figures_kept(tmp_path, capsys):
    """A well-behaved run through both plugins: ``my_rig`` is reached (urllib reads no scheme in it), its
    report's own section and the transport's counters are in summary.json as plain numbers."""
    code, summary, err = _run(
        tmp_path, capsys, "--port", "relay://x", "--phone", "my_rig://desk?report=own", "--duration", "1"
    )
    assert code == 0 and summary["exit"] == "completed", (summary["exit"], err)
    assert summary["phone_admission"]["accepted"] > 500
    assert summary["rig"] == {"frames": 3}
    frames = summary["link"]["transport"]["adapter_frames"]  # its reads on the wall clock: as many as the
    assert type(frames) is int and frames > 0  # machine's load allows, a numpy int64 written as a plain int
