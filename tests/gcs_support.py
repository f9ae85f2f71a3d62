"""Shared by the ground-station tests: HTTP requests to a station, its stream read in a thread, a run played
in a thread with a station watching it, and a quick scenario."""

from __future__ import annotations

import http.client
import json
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from hil import so3
from hil.gcs import GroundStation
from hil.runtime import RunOptions, RunResult, run
from hil.runtime.runlog import read_events
from hil.scenario import Scenario, load_scenario


def quick_scenario(angle_deg: float = 30.0) -> Scenario:
    """cubesat-1u with a shorter slew (as tests/test_runtime.py's quick scenario)."""
    sc = load_scenario("cubesat-1u")
    axis = so3.log(sc.slew.R0.T @ sc.slew.R_target)
    target = sc.slew.R0 @ so3.exp(axis / np.linalg.norm(axis) * np.radians(angle_deg))
    slew = sc.slew.__class__(**{**sc.slew.__dict__, "R_target": target, "max_accel": 0.08})
    return sc.with_changes(slew=slew)


def request(
    station: GroundStation, method: str, path: str, body: Any = None, headers: dict[str, str] | None = None,
    token: str | None = "station",
) -> tuple[int, Any]:  # fmt: skip
    """``(status, decoded JSON or text)`` of one request; ``token="station"``: the station's own in the
    Authorization header, None: none."""
    conn = http.client.HTTPConnection("127.0.0.1", station.port, timeout=10)
    hdrs = {"Host": f"127.0.0.1:{station.port}"}
    if token is not None:
        hdrs["Authorization"] = f"token {station.token if token == 'station' else token}"
    if body is not None and not isinstance(body, bytes):
        body = json.dumps(body).encode()
        hdrs["Content-Type"] = "application/json"
    hdrs.update(headers or {})
    conn.request(method, path, body=body, headers=hdrs)
    try:
        return answer_of(conn)
    finally:
        conn.close()


def answer_of(conn: http.client.HTTPConnection) -> tuple[int, Any]:
    """``(status, decoded JSON or text)`` of the response to the request ``conn`` sent, read whole."""
    answer = conn.getresponse()
    data = answer.read()
    try:
        return answer.status, json.loads(data)
    except ValueError:
        return answer.status, data.decode(errors="replace")


class UplinkLog:
    """What :meth:`hil.gcs.uplink.Uplink.service` needs of a host to log what came and what was turned
    away, kept as records (no board: nothing is carried out)."""

    phase = None  # no run's phase: a hold or slew is not steered at once
    in_control = False
    target = None
    aborting = None  # the run's operator log's: no abort under way

    def __init__(self) -> None:
        self.records: list[dict[str, Any]] = []
        self.events = self
        self.operator = self  # the run's operator log (its ids and abort), kept here as the records

    def used(self, command: Any) -> bool:
        return False

    def write(self, t: float, kind: str, **fields: Any) -> None:
        self.records.append({"kind": kind, **fields})

    def record_command(self, t: float, command: Any, status: str, **fields: Any) -> None:
        self.records.append({"kind": "command", "id": command.id, "status": status, **fields})

    def retarget(self, t: float, target: Any) -> str:
        return "no host here to take a target"


def command(station: GroundStation, body: dict[str, Any], **kw: Any) -> tuple[int, Any]:
    return request(station, "POST", "/api/command", body, **kw)


class RunInThread:
    """``run(scenario, options)`` in a thread, ``station`` observing it; its run directory once it exists."""

    def __init__(self, scenario: Scenario, options: RunOptions, station: GroundStation | None = None) -> None:
        if station is not None:
            options.observer = station.observer
        self.station = station
        self.result: RunResult | None = None
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._run, args=(scenario, options), daemon=True)
        self.out_root = options.out_root
        self.thread.start()

    def _run(self, scenario: Scenario, options: RunOptions) -> None:
        try:
            self.result = run(scenario, options)
        except BaseException as exc:  # raised again in join()
            self.error = exc

    @property
    def run_dir(self) -> Path:
        found = wait_for(lambda: sorted(Path(self.out_root).glob("*/events.jsonl")), 20.0, "a run directory")
        return found[0].parent

    def events(self) -> list[dict[str, Any]]:
        return read_events(self.run_dir / "events.jsonl")[0]

    def wait_event(self, predicate: Callable[[dict[str, Any]], bool], timeout: float = 30.0,
                   what: str = "an event") -> dict[str, Any]:  # fmt: skip
        def found() -> dict[str, Any] | None:
            if self.error is not None:
                raise self.error
            return next((e for e in self.events() if predicate(e)), None)

        return wait_for(found, timeout, what)

    def join(self, timeout: float = 120.0) -> RunResult:
        self.thread.join(timeout)
        if self.thread.is_alive():
            raise TimeoutError("the run did not end")
        if self.error is not None:
            raise self.error
        assert self.result is not None
        return self.result


class ControlStall:
    """Holds a run's control thread in the station's tick hook from run time ``at_s`` until
    :attr:`release` is set (as a blocked write would hold it): :attr:`started` once it holds."""

    def __init__(self, station: GroundStation, at_s: float) -> None:
        self.started = threading.Event()
        self.release = threading.Event()
        feed = station.observer
        real_tick = feed.tick

        def tick(t: float) -> None:
            if t >= at_s and not self.started.is_set():
                self.started.set()
                self.release.wait(60)
            real_tick(t)

        feed.tick = tick  # type: ignore[method-assign]


class StreamReader:
    """The station's ``/api/stream`` read in a thread: ``messages``, ``(monotonic time, event, data)`` per
    message as it arrived; :meth:`close` hangs up."""

    def __init__(self, station: GroundStation, timeout: float = 120.0) -> None:
        self.messages: list[tuple[float, str, Any]] = []
        self.conn = http.client.HTTPConnection("127.0.0.1", station.port, timeout=timeout)
        self.conn.request(
            "GET", f"/api/stream?token={station.token}", headers={"Host": f"127.0.0.1:{station.port}"}
        )
        self.answer = self.conn.getresponse()
        threading.Thread(target=self._run, daemon=True).start()

    def _run(self) -> None:
        buf = b""
        try:
            while chunk := self.answer.read1(1 << 20):
                buf += chunk
                while b"\n\n" in buf:
                    message, buf = buf.split(b"\n\n", 1)
                    fields = dict(line.split(b": ", 1) for line in message.split(b"\n") if b": " in line)
                    if b"event" in fields:
                        data = json.loads(fields.get(b"data", b"null"))
                        self.messages.append((time.monotonic(), fields[b"event"].decode(), data))
        except (OSError, ValueError):
            return  # hung up (by close, or by the station)

    def events(self) -> list[tuple[str, Any]]:
        """``(event, data)`` of every message so far."""
        return [(name, data) for _, name, data in list(self.messages)]

    def between(self, a: float, b: float) -> list[tuple[str, Any]]:
        """``(event, data)`` of the messages that arrived in [a, b) (monotonic s)."""
        return [(name, data) for t, name, data in list(self.messages) if a <= t < b]

    def close(self) -> None:
        self.conn.close()


def read_stream(
    station: GroundStation, timeout: float, until: Callable[[list[tuple[str, Any]]], bool] | None = None
) -> list[tuple[str, Any]]:
    """``(event, data)`` of what the station's stream sends in ``timeout`` s, or until ``until(messages)``
    holds (else a timeout naming the stream's end)."""
    reader = StreamReader(station, timeout + 5)
    try:
        if until is None:
            time.sleep(timeout)
        else:
            wait_for(lambda: until(reader.events()), timeout, "the stream's end")
        return reader.events()
    finally:
        reader.close()


def wait_for(predicate: Callable[[], Any], timeout: float, what: str) -> Any:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = predicate()
        if value:
            return value
        time.sleep(0.05)
    raise TimeoutError(f"no {what} within {timeout} s")


@contextmanager
def replay_seen_at(browser: Any, run_dir: Path, rows: int, t: float) -> Iterator[GroundStation]:
    """The run in ``run_dir`` replayed by a ground station in ``browser`` (selenium), all of its ``rows``
    loaded and the page's timeline moved to ``t`` (s): what an operator reviewing the run sees there."""
    from browser_support import js

    with GroundStation.replay(run_dir, bind="127.0.0.1:0") as station:
        browser.get(station.url)
        wait_for(lambda: js(browser, "return window.gcs.state.status.state") == "finished", 20, "the replay")
        wait_for(lambda: js(browser, "return window.gcs.state.store.n") == rows, 10, "every row")
        js(browser, """const s = document.getElementById('timeline'); s.value = arguments[0];
                       s.dispatchEvent(new Event('input'));""", t)  # fmt: skip
        yield station
