"""The ground station's cost to the control loop, and what the page gets.

One real-time run at **100 Hz control** (the runtime against ``spawn://firmware-sim`` with its world on a
pty, the world's phone streaming over loopback UDP, as in ``bench_runtime``; where the world cannot keep
real time here, the board's internal actuator model and a still stand-in phone, the rows then saying ``no
world``), with a live ground station observing it (:class:`hil.gcs.GroundStation`, its pump encoding and
holding every row whether or not a browser reads). After the slew starts:

1. window **A**, no page attached: the control task's lateness after its absolute deadline (the
   scheduler's own samples, one per control tick), p50 and p99;
2. window **C**: a reader that takes the downlink and draws nothing, in its own process — what serving
   the downlink costs the host's process, apart from what drawing it costs the machine;
3. a real headless chromium (Selenium + chromedriver, as the browser tests) opens the page; once it has
   its history, window **B**, page attached: the same lateness figures, the page's redraws with new data
   per second (``window.gcs.stats.dataRenders``), the downlink's bytes per second on the socket (the
   hub's ``bytes_sent``), the browser's CPU;
4. window **D**: the same browser with its processes reniced to :data:`NICE` (below the run) — a browser
   on the machine that runs the loop, as an operator would set it up;
5. an Abort from the uplink ends the run.

Figures: lateness p50/p99 with the page (B, D) and with the bare reader (C) against the same run without
any (A) — the target is no measurable change; page updates per second against the 20 Hz target; downlink
bytes/s against the bytes/s the same run writes to ``telemetry.csv`` (the downlink adds the live columns
and link statistics, and sends JSON). The feed's dropped rows go into the note (they should be 0), with
the machine's load average: on a shared 2-core machine the lateness percentiles move with it.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import urlencode

import numpy as np

from bench.bench_runtime import SCENARIO, WORLD_BUDGET, _at_rate, _phone_url, _still_phone, _world_cost
from bench.common import Result
from hil.gcs import GroundStation
from hil.runtime import RunOptions
from hil.runtime import run as run_scenario
from hil.runtime.observer import RunStart
from hil.scenario import load_scenario

NAME = "gcs"
RATE_HZ = 100.0
NICE = 10  # window D: the browser's processes at this niceness (the run's at 0)
CHROMIUM = os.environ.get("VSCMG_HIL_CHROMIUM", "/usr/bin/chromium")
CHROMEDRIVER = os.environ.get("VSCMG_HIL_CHROMEDRIVER", "/usr/bin/chromedriver")


@dataclass
class _Recorder:
    """The station's observer, and the wall time of every control tick (index = the scheduler's run
    number, which is also the index of its lateness sample)."""

    inner: Any
    ticks: list[float] = field(default_factory=list)
    start: RunStart | None = None

    def started(self, start: RunStart) -> None:
        self.start = start
        self.inner.started(start)

    def row(self, row: Any) -> None:
        self.inner.row(row)

    def event(self, record: Any) -> None:
        self.inner.event(record)

    def tick(self, t: float) -> None:
        self.ticks.append(time.monotonic())
        self.inner.tick(t)

    def finished(self, summary: Any) -> None:
        self.inner.finished(summary)

    def lateness_us(self, t0: float, t1: float) -> np.ndarray:
        """Control lateness samples (µs) of the ticks between wall times ``t0`` and ``t1``."""
        assert self.start is not None
        control = next(t for t in self.start.scheduler.tasks if t.name == "control")
        samples = control.stats.lateness
        ticks = np.asarray(self.ticks[: samples.size])
        return samples[(ticks >= t0) & (ticks < t1)] * 1e6


def _browser() -> Any:
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    flags = (
        "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-sync",
        "--disable-background-networking", "--disable-component-update", "--window-size=1600,1000",
    )  # fmt: skip
    for flag in (*flags, f"--user-data-dir={tempfile.mkdtemp(prefix='bench-gcs-')}"):
        options.add_argument(flag)
    return webdriver.Chrome(options=options, service=Service(CHROMEDRIVER))


def _wait(predicate: Any, timeout: float, what: str) -> Any:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = predicate()
        if value:
            return value
        time.sleep(0.05)
    raise TimeoutError(f"bench_gcs: no {what} within {timeout} s")


def _measure(window_s: float, world: bool) -> dict[str, Any]:
    import http.client
    import json

    if not (shutil.which(CHROMIUM) or Path(CHROMIUM).exists()):
        raise RuntimeError(f"bench_gcs needs a headless chromium at {CHROMIUM} (Debian's chromium)")
    scenario = _at_rate(load_scenario(SCENARIO), RATE_HZ)
    phone = _phone_url()
    query = scenario.firmware_sim_options() + ([("world", SCENARIO), ("phone", phone)] if world else [])
    out: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="bench-gcs-") as tmp, contextlib.ExitStack() as stack:
        if not world:
            stack.enter_context(_still_phone(phone))
        station = stack.enter_context(GroundStation.live(bind="127.0.0.1:0"))
        recorder = _Recorder(station.observer)
        options = RunOptions(port="spawn://firmware-sim?" + urlencode(query), phone=phone,
                             duration_s=4 * window_s + 20, out_root=Path(tmp), observer=recorder)  # fmt: skip
        result: dict[str, Any] = {}

        def play() -> None:
            try:
                result["r"] = run_scenario(scenario, options)
            except BaseException as exc:  # raised in this thread by _started
                result["error"] = exc

        def started() -> bool:
            if "error" in result:
                raise RuntimeError(f"bench_gcs: the run failed: {result['error']}") from result["error"]
            if "r" in result:
                raise RuntimeError(f"bench_gcs: the run ended early: {result['r'].summary.get('exit')}")
            return any(e.get("kind") == "slew_start" for e in _events(tmp))

        thread = threading.Thread(target=play, daemon=True)
        thread.start()
        _wait(started, 60, "slew start")
        a0 = time.monotonic()
        time.sleep(window_s)
        a1 = time.monotonic()
        reader = subprocess.Popen([sys.executable, "-c", _RAW_READER, str(station.port), station.token])
        time.sleep(1.0)
        c0 = time.monotonic()
        time.sleep(window_s)
        c1 = time.monotonic()
        reader.terminate()
        reader.wait(10)
        browser = _browser()
        stack.callback(browser.quit)
        browser.get(station.url)
        _wait(lambda: browser.execute_script("return window.gcs.stats.rows") > 0, 20, "page data")
        time.sleep(1.5)  # the history's burst is over
        b0 = time.monotonic()
        browser_cpu0 = _cpu_s(browser.service.process.pid)
        renders0 = browser.execute_script("return window.gcs.stats.dataRenders")
        sent0 = station.hub.stats.bytes_sent
        csv0 = _csv_bytes(tmp)
        time.sleep(window_s)
        b1 = time.monotonic()
        browser_cpu1 = _cpu_s(browser.service.process.pid)
        renders1 = browser.execute_script("return window.gcs.stats.dataRenders")
        sent1 = station.hub.stats.bytes_sent
        csv1 = _csv_bytes(tmp)
        for pid in _tree(browser.service.process.pid):  # the same page, the browser below the run's priority
            with contextlib.suppress(OSError):
                os.setpriority(os.PRIO_PROCESS, pid, NICE)
        time.sleep(1.0)
        d0 = time.monotonic()
        renders_d0 = browser.execute_script("return window.gcs.stats.dataRenders")
        time.sleep(window_s)
        d1 = time.monotonic()
        renders_d1 = browser.execute_script("return window.gcs.stats.dataRenders")
        conn = http.client.HTTPConnection("127.0.0.1", station.port, timeout=10)
        headers = {"Content-Type": "application/json", "Authorization": f"token {station.token}"}
        conn.request("POST", "/api/command", body=json.dumps({"command": "abort"}), headers=headers)
        conn.getresponse().read()
        thread.join(60)
        out.update(
            a=recorder.lateness_us(a0, a1), b=recorder.lateness_us(b0, b1), c=recorder.lateness_us(c0, c1),
            d=recorder.lateness_us(d0, d1), updates_niced_hz=(renders_d1 - renders_d0) / (d1 - d0),
            browser_cpu=(browser_cpu1 - browser_cpu0) / (b1 - b0),
            updates_hz=(renders1 - renders0) / (b1 - b0), bytes_s=(sent1 - sent0) / (b1 - b0),
            csv_bytes_s=(csv1 - csv0) / (b1 - b0), feed=station.stats()["feed"],
            exit=result["r"].summary.get("exit") if "r" in result else "no result",
        )  # fmt: skip
    return out


# A downlink reader that draws nothing (reads the stream and drops it), in its own process: what serving
# the downlink costs the host's process, apart from what a browser's drawing costs the machine.
_RAW_READER = r"""
import socket, sys
s = socket.create_connection(("127.0.0.1", int(sys.argv[1])))
s.sendall(f"GET /api/stream?token={sys.argv[2]} HTTP/1.0\r\nHost: 127.0.0.1\r\n\r\n".encode())
while s.recv(1 << 16):
    pass
"""


def _tree(pid: int) -> list[int]:
    """``pid`` and its descendants (Linux /proc)."""
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        if p in out:
            continue
        out.append(p)
        with contextlib.suppress(OSError):
            for task in Path(f"/proc/{p}/task").iterdir():
                todo += [int(child) for child in (task / "children").read_text().split()]
    return out


def _cpu_s(pid: int) -> float:
    """CPU seconds (user + system, reaped children's too) used so far by ``pid`` and its descendants."""
    tick = os.sysconf("SC_CLK_TCK")
    total = 0.0
    for p in _tree(pid):
        with contextlib.suppress(OSError, IndexError, ValueError):
            fields = Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()
            total += (int(fields[11]) + int(fields[12]) + int(fields[13]) + int(fields[14])) / tick
    return total


def _events(tmp: str) -> list[dict[str, Any]]:
    import json

    out = []
    for path in Path(tmp).glob("*/events.jsonl"):
        for line in path.read_text().splitlines():
            with contextlib.suppress(ValueError):
                out.append(json.loads(line))
    return out


def _csv_bytes(tmp: str) -> int:
    return sum(p.stat().st_size for p in Path(tmp).glob("*/telemetry.csv"))


def run(quick: bool) -> list[Result]:
    window_s = 4.0 if quick else 10.0
    load = os.getloadavg()[0]
    cost = _world_cost()
    world = cost < WORLD_BUDGET
    m = _measure(window_s, world)
    a, b, c, d = m["a"], m["b"], m["c"], m["d"]
    where = "with its world" if world else f"no world (the world needs {cost:.2f} CPU s per s here)"

    def pct(x: np.ndarray, q: float) -> float:
        return float(np.percentile(x, q)) if x.size else float("nan")

    note = (
        f"100 Hz control against spawn://firmware-sim {where}; windows of {window_s:.0f} s after the slew "
        f"starts: A {a.size} ticks without a page, C {c.size} with a reader that draws nothing (own process),"
        " "
        f"B {b.size} with the page in headless chromium (which used {m['browser_cpu']:.2f} CPU s per s), "
        f"D {d.size} with the same browser at nice {NICE} ({m['updates_niced_hz']:.1f} page updates/s); "
        f"feed dropped {m['feed']['dropped_rows']} rows; run exit {m['exit']!r}; load average {load:.2f} on "
        f"{os.cpu_count()} CPUs"
    )
    return [
        Result(NAME, "control lateness p50 at 100 Hz, page attached", pct(b, 50), "us",
               "same run, no page", pct(a, 50), False, note),
        Result(NAME, "control lateness p99 at 100 Hz, page attached", pct(b, 99), "us",
               "same run, no page", pct(a, 99), False),
        Result(NAME, f"control lateness p50 at 100 Hz, page attached, browser nice {NICE}", pct(d, 50), "us",
               "same run, no page", pct(a, 50), False),
        Result(NAME, f"control lateness p99 at 100 Hz, page attached, browser nice {NICE}", pct(d, 99), "us",
               "same run, no page", pct(a, 99), False),
        Result(NAME, "control lateness p50 at 100 Hz, downlink read, not drawn", pct(c, 50), "us",
               "same run, no page", pct(a, 50), False),
        Result(NAME, "control lateness p99 at 100 Hz, downlink read, not drawn", pct(c, 99), "us",
               "same run, no page", pct(a, 99), False),
        Result(NAME, "page updates with new data", m["updates_hz"], "Hz", "target", 20.0, True,
               "headless chromium, redraws of plots, 3D view and panels that had new rows"),
        Result(NAME, "downlink on the socket", m["bytes_s"] / 1e3, "kB/s", "telemetry.csv written",
               m["csv_bytes_s"] / 1e3, False, "SSE: rows with the live columns, events, link statistics"),
    ]  # fmt: skip
