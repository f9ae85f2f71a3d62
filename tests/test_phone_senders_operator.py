"""Another phone on the phone's port, made visible while the run runs (docs/formats.md, "One phone per
receiver"; docs/gcs.md): the receiver's one-phone rule — the phone followed, another phone heard, a
hand-over, other phones quiet again — as ``events.jsonl`` records with the sender and the counts, and on
the ground station: its event list, its phone panel's live counts, and the "another phone" caution.

Through the real interfaces: a real-time run (``hil.runtime.run``) whose simulated world streams its phone
over UDP to the run's real receiver, a second UDP socket of the test's own streaming to the same port as
another phone, and a third one as the phone's app restarted from a new source port while the world's phone
is silent (its ``phone_gap``); the live ground station's stream read from a socket while the run goes on,
and the run directory replayed as ``hil gcs RUN_DIR`` serves it. The receiver's own bookkeeping (the rate
limit, the bounded queue, the quiet bound, a snapshot taken while datagrams arrive) with real sockets and
a clock moved by the test.
"""

from __future__ import annotations

import contextlib
import json
import socket
import threading
import time
from dataclasses import dataclass
from typing import Any

import pytest
from browser_support import chromium, js, page_errors
from gcs_support import RunInThread, quick_scenario, request, wait_for

from hil.cli.run import format_summary
from hil.estimation.sensors import SensorKind, SensorSample
from hil.gcs import GroundStation
from hil.gcs.info import SENDER_COLUMNS
from hil.link.sources.phone_udp import PhoneUdpReceiver, encode_datagram
from hil.link.sources.senders import SWITCH_AFTER_S
from hil.link.sources.stream import MAX_SENDER_EVENTS, NEW_SENDER_LOGS, OTHERS_QUIET_S
from hil.runtime import RunOptions, RunResult
from hil.runtime.runlog import read_events

OTHER_ALARM = "phone_other:streaming"
RULE = ("phone_following", "phone_other", "phone_switch", "phone_others_quiet")
GAP_AT_S, GAP_S = 4.0, 4.0  # the world's phone silent (board time, s): the followed phone gone
# The restarted app streams ~2.55 s into that silence: past the hand-over bound (2 s), before the world's
# phone is back (4 s: 1.4 s to spare on a loaded machine), and less than 2 s before it is back (so the
# world's phone is another phone until the app has been silent 2 s).
DURATION_S = 12.0  # from the slew's start (~3.8 s): past the second quiet (~8.6 s + OTHERS_QUIET_S)


def _gyro(t_s: float, x: float = 0.0) -> SensorSample:
    return SensorSample(t_s, SensorKind.GYR, (x, 0.0, 0.0))


class App:
    """A phone app's UDP socket, a source port of its own (as SensaGram has), streaming to ``to``."""

    def __init__(self, to: tuple[str, int]) -> None:
        self.to = to
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.name = f"127.0.0.1:{self.sock.getsockname()[1]}"

    def stream(self, n: int, spacing_s: float = 0.005) -> None:
        for k in range(n):
            self.sock.sendto(encode_datagram(_gyro(1.0 + spacing_s * k, float(k))), self.to)
            time.sleep(spacing_s)

    def close(self) -> None:
        self.sock.close()


class Stream:
    """A ground station's downlink read from a socket by a thread of its own, as a browser reads it."""

    def __init__(self, station: GroundStation) -> None:
        self.sock = socket.create_connection(("127.0.0.1", station.port), timeout=60)
        self.sock.sendall(
            f"GET /api/stream?token={station.token} HTTP/1.0\r\nHost: 127.0.0.1\r\n\r\n".encode()
        )
        self._data = bytearray()
        self._lock = threading.Lock()
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self) -> None:
        try:
            while chunk := self.sock.recv(1 << 20):
                with self._lock:
                    self._data += chunk
        except OSError:  # closed by the test
            pass

    def text(self) -> str:
        with self._lock:
            return self._data.decode()

    def messages(self) -> list[tuple[str, Any]]:
        """Every complete SSE message so far: ``(event, data)``."""
        body = self.text().partition("\r\n\r\n")[2]
        out = []
        for m in body.split("\n\n")[:-1]:
            if m.startswith("event: "):
                name, _, data = m.partition("\ndata: ")
                out.append((name.removeprefix("event: "), json.loads(data)))
        return out

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_RDWR)  # wakes the reader's recv
        self.sock.close()
        self.thread.join(10)


def _of(messages: list[tuple[str, Any]], name: str) -> list[Any]:
    """The items of every ``name`` message (rows, events, ...), in order."""
    out: list[Any] = []
    for event, data in messages:
        if event == name:
            out += data["rows"] if name == "rows" else data if isinstance(data, list) else [data]
    return out


@dataclass
class PhoneRun:
    result: RunResult
    events: list[dict[str, Any]]  # events.jsonl
    live: list[tuple[str, Any]]  # the live ground station's stream
    seen_while_running: bool  # the first phone_other was on the live stream before the run ended
    other: str  # the other phone streaming alongside
    restarted: str  # the app restarted from a new port while the world's phone was silent
    ack_status: int


@pytest.fixture(scope="module")
def phone_run(tmp_path_factory: pytest.TempPathFactory) -> PhoneRun:
    """One real-time run watched by a live ground station: the world's phone followed; another phone
    streams 20 datagrams alongside it (its caution acknowledged through the station's API); the world's
    phone falls silent and, 2 s on, a new app is followed; the world's phone back is another phone until
    the new app has been silent 2 s, then followed again."""
    out = tmp_path_factory.mktemp("runs")
    sc = quick_scenario().with_changes(fault_options={"phone_gap": [f"{GAP_AT_S}:{GAP_S}"]})
    apps: list[App] = []
    with GroundStation.live(bind="127.0.0.1:0") as station:
        stream = Stream(station)
        running = RunInThread(sc, RunOptions(out_root=out, lockstep=False, duration_s=DURATION_S), station)
        try:
            url = running.wait_event(lambda e: e["kind"] == "phone_listening", 60, "the receiver")["url"]
            host, port = url.removeprefix("udp://").rsplit(":", 1)
            running.wait_event(lambda e: e["kind"] == "phone_following", 30, "the world's phone followed")
            other = App((host, int(port)))
            apps.append(other)
            other.stream(20)
            raised = running.wait_event(lambda e: e["kind"] == "phone_other", 30, "another phone recorded")
            ack_status, _ = request(
                station, "POST", "/api/ack", {"alarm": OTHER_ALARM, "raised_t": raised["t"]}
            )
            wait_for(lambda: '"kind":"phone_other"' in stream.text(), 10, "the record on the live stream")
            seen_while_running = running.thread.is_alive()
            running.wait_event(lambda e: e["kind"] == "phone_gap", 30, "the world's phone silent")
            time.sleep(SWITCH_AFTER_S + 0.3)  # the gap is told 0.25 s into the silence: 2.55 s of it
            restarted = App((host, int(port)))
            apps.append(restarted)
            restarted.stream(5)
            result = running.join(120)
        finally:
            for app in apps:
                app.close()
        station.close()  # a last pump cycle, then the streams end
        stream.thread.join(30)
        live = stream.messages()
        stream.close()
    assert result.run_dir is not None
    events, bad = read_events(result.run_dir / "events.jsonl")
    assert bad == 0
    return PhoneRun(result, events, live, seen_while_running, other.name, restarted.name, ack_status)


def _rule(events: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [e for e in events if e["kind"] in RULE]


# ----------------------------------------------------------------------------------------- the record
def test_a_run_records_the_phone_followed_another_phone_each_hand_over_and_the_others_quiet(phone_run):
    events = phone_run.events
    rule = _rule(events)
    assert [e["kind"] for e in rule] == [
        "phone_following",  # the world's phone, the first heard
        "phone_other",  # the test's other phone, alongside: dropped
        "phone_others_quiet",  # OTHERS_QUIET_S after its last datagram
        "phone_switch",  # the world's phone silent, the restarted app followed
        "phone_other",  # the world's phone back: another phone now
        "phone_switch",  # the restarted app silent: the world's phone followed again
        "phone_others_quiet",
    ], [(e["t"], e["kind"]) for e in rule]
    world = rule[0]["sender"]
    first, quiet, to_app, back, to_world, quiet_again = rule[1:]
    assert (first["sender"], first["following"], first["new"]) == (phone_run.other, world, True)
    assert (first["other_phones"], first["phone_switches"]) == (1, 0) and first["other_phone_messages"] >= 1
    assert quiet["other_phone_messages"] == quiet["other_phone_samples"] == 20  # every datagram, counted
    assert quiet["silent_s"] >= OTHERS_QUIET_S and quiet["t"] - first["t"] >= OTHERS_QUIET_S - 0.2
    assert (to_app["sender"], to_app["previous"], to_app["phone_switches"]) == (phone_run.restarted, world, 1)
    assert to_app["silent_s"] >= SWITCH_AFTER_S
    assert (back["sender"], back["following"], back["new"], back["other_phones"]) == (
        world, phone_run.restarted, True, 2,
    )  # fmt: skip
    assert (to_world["sender"], to_world["previous"], to_world["phone_switches"]) == (
        world,
        phone_run.restarted,
        2,
    )
    # the counts only grow, and the last record's are the run's final ones (nothing dropped after it)
    for name in ("other_phones", "other_phone_messages", "other_phone_samples", "phone_switches"):
        values = [e[name] for e in rule]
        assert values == sorted(values), name
        assert quiet_again[name] == phone_run.result.summary["phone"][name], name
    assert phone_run.result.summary["phone"]["following"] == world
    assert phone_run.result.summary["phone"]["unrecorded_sender_events"] == 0
    printed = format_summary(phone_run.result.summary)  # what hil run and hil report print
    phone = phone_run.result.summary["phone"]
    assert (
        f"following {world}; {phone['other_phones']} other(s) dropped "
        f"({phone['other_phone_messages']} messages), {phone['phone_switches']} hand-over(s)"
    ) in printed, printed
    # the operator's acknowledgement of the caution, logged with the occurrence it names
    assert phone_run.ack_status == 202
    ack = next(e for e in events if e["kind"] == "alarm_ack")
    assert (ack["alarm"], ack["raised_t"]) == (OTHER_ALARM, first["t"])
    ts = [e["t"] for e in events]
    assert ts == sorted(ts)  # events.jsonl stays in time order


# ----------------------------------------------------------------------------------------- the page's feeds
def test_the_live_ground_station_carries_the_records_the_counts_and_the_caution(phone_run):
    live = phone_run.live
    info = _of(live, "info")[0]
    caution = next(a for a in info["alarms"] if a["key"] == OTHER_ALARM)
    assert (caution["op"], caution["raise_on"], caution["clear_on"]) == (
        "event",
        "phone_other",
        "phone_others_quiet",
    )
    assert caution["column"] in info["columns"] and caution["severity"] == "warning"
    # every record, as events.jsonl has it, and the first while the run was still going on
    streamed = _of(live, "events")
    assert _rule(streamed) == _rule(phone_run.events) and phone_run.seen_while_running
    assert any(e["kind"] == "alarm_ack" and e["alarm"] == OTHER_ALARM for e in streamed)
    # the counts in every row, as the receiver had them at that tick
    columns = info["columns"]
    assert set(SENDER_COLUMNS) <= set(columns)
    rows = _of(live, "rows")
    t_of, col = columns.index("t"), {c: columns.index(c) for c in SENDER_COLUMNS}
    counted = [
        (r[t_of], *(r[col[c]] for c in SENDER_COLUMNS))
        for r in rows
        if r[col["phone_other_phones"]] is not None
    ]
    assert counted and len(counted) > 0.9 * len(rows)  # from the first estimator tick on
    rule = _rule(phone_run.events)
    first = rule[1]
    assert all(n == 0 for t, n, *_ in counted if t < first["t"] - 1e-9)
    assert all(n >= 1 for t, n, *_ in counted if t > first["t"] + 0.1)
    for k in range(1, 4):
        values = [row[k] for row in counted]
        assert values == sorted(values)
    # updated between the records, not only at them: the messages count moves while the world's phone
    # is another phone (between the records of its return and of the hand-over back)
    back, to_world = rule[4], rule[5]
    moving = {m for t, _, m, _ in counted if back["t"] <= t <= to_world["t"]}
    assert len(moving) > 5, moving
    final = phone_run.result.summary["phone"]
    assert counted[-1][1:] == (final["other_phones"], final["other_phone_messages"], final["phone_switches"])
    status = [s for s in _of(live, "status") if s.get("state") == "ended"]
    assert status and status[-1]["summary"]["phone"]["other_phones"] == 2


def test_hil_gcs_replays_the_records_from_the_run_directory(phone_run):
    run_dir = phone_run.result.run_dir
    with GroundStation.replay(run_dir, bind="127.0.0.1:0") as station:
        stream = Stream(station)
        wait_for(lambda: '"state":"finished"' in stream.text(), 30, "the replay read to its end")
        replay = stream.messages()
        stream.close()
    info = _of(replay, "info")[0]
    assert any(a["key"] == OTHER_ALARM for a in info["alarms"])
    assert not set(SENDER_COLUMNS) & set(info["columns"])  # not telemetry.csv's: the page uses the records
    assert _rule(_of(replay, "events")) == _rule(phone_run.events)
    finished = next(s for s in _of(replay, "status") if s.get("state") == "finished")
    assert (
        finished["summary"]["phone"]["other_phone_messages"]
        == phone_run.result.summary["phone"]["other_phone_messages"]
    )


# ----------------------------------------------------------------------------------------- the page
@pytest.fixture(scope="module")
def browser():
    yield from chromium()


def _cells(browser) -> dict[str, Any]:
    """The phone panel's rule cells, the caution's alarm rows and the event list's rows, in one script."""
    return js(
        browser,
        """const cell = (id) => { const el = document.getElementById(id);
             return {text: el.textContent, stale: el.classList.contains('stale'), age: el.dataset.age || '',
                     alarm: el.dataset.alarm || ''}; };
           const td = (tr, c) => tr.querySelector('td.' + c).textContent;
           const rows = [...document.querySelectorAll(`#alarms tr[data-key="${arguments[0]}"]`)].map(
             (tr) => ({cls: tr.className, raised: Number(tr.dataset.raised), cleared: td(tr, 'cleared'),
                       ack: td(tr, 'ack')}));
           const kinds = [...document.querySelectorAll('#events tbody tr')].map(
             (tr) => [tr.dataset.kind, tr.className]);
           return {following: cell('phone-following'), others: cell('phone-others'),
                   messages: cell('phone-other-messages'), switches: cell('phone-switches'), rows, kinds};""",
        OTHER_ALARM,
    )


@pytest.mark.browser
def test_the_page_shows_the_phone_followed_the_others_dropped_and_the_caution(phone_run, browser, tmp_path):
    """The run replayed in headless chromium: at its end, the phone panel shows the phone followed and the
    counts of the run's summary, marked as of the end of the run (never as live); the alarm list has the
    caution twice, each cleared by its quiet record, the first acknowledged; the event list shows the
    records (the other phone and the hand-overs in amber). Scrubbed back into the first occurrence, the
    panel's other-phones cell is coloured by the caution and its counts are those of the newest record,
    marked as of its time."""
    rule = _rule(phone_run.events)
    final = phone_run.result.summary["phone"]
    with GroundStation.replay(phone_run.result.run_dir, bind="127.0.0.1:0") as station:
        browser.get(station.url)
        wait_for(lambda: js(browser, "return window.gcs.state.status.state") == "finished", 30, "the replay")
        wait_for(
            lambda: _cells(browser)["following"]["age"] == "at the end of the run", 10, "the end's counts"
        )
        end = _cells(browser)
        assert end["following"]["text"] == final["following"] == rule[0]["sender"]
        assert [end[k]["text"] for k in ("others", "messages", "switches")] == [
            str(final["other_phones"]), str(final["other_phone_messages"]), str(final["phone_switches"])
        ]  # fmt: skip
        assert all(end[k]["stale"] for k in ("following", "others", "messages", "switches"))
        assert [r["raised"] for r in reversed(end["rows"])] == [rule[1]["t"], rule[4]["t"]]
        first_row = end["rows"][-1]
        assert first_row["cleared"] == f"{rule[2]['t']:.2f}" and first_row["ack"].startswith("✓")
        assert end["rows"][0]["cleared"] == f"{rule[6]['t']:.2f}"
        kinds = dict(end["kinds"])
        assert (
            kinds["phone_other"] == "warn" and kinds["phone_switch"] == "warn" and "phone_following" in kinds
        )
        browser.save_screenshot(str(tmp_path / "end.png"))
        # scrubbed into the first occurrence: coloured, the first record's counts, as of its time
        at = (rule[1]["t"] + rule[2]["t"]) / 2
        js(browser, """const s = document.getElementById('timeline'); s.value = arguments[0];
                       s.dispatchEvent(new Event('input'));""", at)  # fmt: skip
        wait_for(
            lambda: _cells(browser)["others"]["alarm"] == "warning", 10, "the caution active at the cursor"
        )
        mid = _cells(browser)
        assert mid["others"]["text"] == "1" and mid["others"]["age"] == f"as of {rule[1]['t']:.1f} s"
        assert mid["following"]["text"] == rule[0]["sender"] and not mid["following"]["stale"]  # a record's
        assert "active" in mid["rows"][0]["cls"] and len(mid["rows"]) == 1
        browser.save_screenshot(str(tmp_path / "caution.png"))
    assert not page_errors(browser)


# ----------------------------------------------------------------------------------------- the receiver
class Clock:
    """A receiver's monotonic clock, moved by the test (s)."""

    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def _send(receiver: PhoneUdpReceiver, app: App, n: int = 1) -> None:
    """``n`` datagrams from ``app``, each taken by the receiver before the next (the test's clock stands)."""
    for _ in range(n):
        before = _handled(receiver)
        app.sock.sendto(encode_datagram(_gyro(1.0)), app.to)
        deadline = time.monotonic() + 10.0
        while _handled(receiver) <= before:
            assert time.monotonic() < deadline, "the receiver did not take the datagram in time"
            time.sleep(0.0005)


def _handled(receiver: PhoneUdpReceiver) -> int:
    st_ = receiver.stats
    return st_.messages + st_.bad_messages + st_.other_phone_messages


def _to(receiver: PhoneUdpReceiver) -> tuple[str, int]:
    host, port = receiver.url.removeprefix("udp://").rsplit(":", 1)
    return host, int(port)


def test_each_moment_is_taken_once_with_the_counts_and_the_quiet_bound_is_the_receivers_clock():
    clock = Clock()
    with PhoneUdpReceiver("udp://127.0.0.1:0", clock=clock) as receiver:
        phone, other, restarted = (App(_to(receiver)) for _ in range(3))
        _send(receiver, phone, 3)
        _send(receiver, other, 4)
        status = receiver.senders()
        assert [(e.kind, e.fields["sender"]) for e in status.events] == [
            ("phone_following", phone.name), ("phone_other", other.name)
        ]  # fmt: skip
        assert status.events[1].fields["other_phone_messages"] == 1  # as at the moment, not at the read
        assert (status.following, status.other_phones, status.other_phone_messages) == (phone.name, 1, 4)
        assert status.others_streaming and receiver.senders().events == ()  # taken once
        for _ in range(40):  # the followed phone streams on (every 0.1 s); the other one is silent
            clock.now += 0.1
            _send(receiver, phone)
        clock.now += OTHERS_QUIET_S - 4.0 - 0.01
        assert receiver.senders().events == ()
        clock.now += 0.01
        quiet = receiver.senders()
        assert [e.kind for e in quiet.events] == ["phone_others_quiet"] and not quiet.others_streaming
        assert quiet.events[0].fields["silent_s"] == pytest.approx(OTHERS_QUIET_S)
        # the same phone again after a quiet: recorded again (not new), so the caution is raised again
        _send(receiver, other)
        again = receiver.senders().events
        assert [(e.kind, e.fields["new"], e.fields["other_phones"]) for e in again] == [
            ("phone_other", False, 1)
        ]
        # the followed phone silent past the bound: the next new sender is followed, and that is recorded
        _send(receiver, phone)
        clock.now += SWITCH_AFTER_S + 0.5
        _send(receiver, restarted)
        (switch,) = receiver.senders().events
        assert (switch.kind, switch.fields["sender"], switch.fields["previous"]) == (
            "phone_switch", restarted.name, phone.name,
        )  # fmt: skip
        assert (
            switch.fields["silent_s"] == pytest.approx(SWITCH_AFTER_S + 0.5)
            and switch.fields["phone_switches"] == 1
        )
        for app in (phone, other, restarted):
            app.close()


def test_a_spray_of_senders_is_recorded_under_the_log_s_rate_limit():
    """Forty new senders within a second: NEW_SENDER_LOGS records (as many as log lines); the next one a
    second later says how many went unrecorded before it."""
    clock = Clock()
    with PhoneUdpReceiver("udp://127.0.0.1:0", clock=clock) as receiver:
        phone = App(_to(receiver))
        _send(receiver, phone)
        spray = [App(_to(receiver)) for _ in range(40)]
        for app in spray:
            _send(receiver, app)
        others = [e for e in receiver.senders().events if e.kind == "phone_other"]
        assert [e.fields["sender"] for e in others] == [a.name for a in spray[:NEW_SENDER_LOGS]]
        clock.now += 1.0
        late = App(_to(receiver))
        _send(receiver, late)
        (record,) = receiver.senders().events
        assert (
            record.fields["sender"] == late.name
            and record.fields["not_recorded_before"] == 40 - NEW_SENDER_LOGS
        )
        assert record.fields["other_phones"] == 41
        for app in (phone, late, *spray):
            app.close()


def test_the_records_waiting_for_a_run_that_does_not_read_them_are_bounded_and_counted():
    clock = Clock()
    with PhoneUdpReceiver("udp://127.0.0.1:0", clock=clock) as receiver:
        phone = App(_to(receiver))
        _send(receiver, phone)
        apps = []
        for _ in range(MAX_SENDER_EVENTS + 5):  # one new sender a second, each recorded
            clock.now += 1.0
            _send(receiver, phone)  # the followed phone keeps streaming: no hand-over
            apps.append(App(_to(receiver)))
            _send(receiver, apps[-1])
        events = receiver.senders().events
        assert len(events) == MAX_SENDER_EVENTS and receiver.stats.unrecorded_sender_events == 6
        assert events[-1].fields["sender"] == apps[-1].name  # the newest kept, the oldest dropped
        for app in (phone, *apps):
            app.close()


def test_a_snapshot_taken_while_datagrams_arrive_is_consistent():
    """The runtime's reads (the control thread) while the network thread takes another phone's flood:
    each snapshot's counts only grow, every record is taken exactly once, and the last read agrees with
    the receiver's counters."""
    with PhoneUdpReceiver("udp://127.0.0.1:0") as receiver:
        phone, other = App(_to(receiver)), App(_to(receiver))
        _send(receiver, phone)
        stop = threading.Event()

        def flood() -> None:
            k = 0
            while not stop.is_set() and k < 20_000:
                other.sock.sendto(encode_datagram(_gyro(2.0 + 1e-4 * k)), other.to)
                k += 1

        thread = threading.Thread(target=flood)
        thread.start()
        reads, records = [], []
        deadline = time.monotonic() + 1.0
        while time.monotonic() < deadline:
            s = receiver.senders()
            reads.append((s.other_phones, s.other_phone_messages, s.other_phone_samples))
            records += s.events
        stop.set()
        thread.join()
        wait_for(
            lambda: receiver.senders().other_phone_messages == receiver.stats.other_phone_messages, 5, ""
        )
        assert reads == sorted(reads) and reads[-1][1] > 0
        assert [e.kind for e in records] == ["phone_following", "phone_other"]
        last = receiver.senders()
        assert last.other_phone_messages == receiver.stats.other_phone_messages == last.other_phone_samples
        phone.close()
        other.close()
