"""The ground station's cost to the control loop, and what the page gets — on the tornado server and, in
the same run, on the earlier threaded one (``bench/gcs_threaded_server.py``).

One real-time run at **100 Hz control** (the runtime against ``spawn://firmware-sim`` with its world on a
pty, the world's phone streaming over loopback UDP, as in ``bench_runtime``; where the world cannot keep
real time here, the board's internal actuator model and a still stand-in phone, the rows then saying ``no
world``), observed by **two** live ground stations at once (:class:`_Fanout`): one on the tornado server
(:class:`hil.gcs.server.GcsServer`), one on the threaded server it replaced. Both pumps encode every row
in every window, so the windows differ only in what is attached. After the slew starts:

1. window **A**, nothing attached: the control task's lateness after its absolute deadline (the
   scheduler's own samples, one per control tick), p50 and p99;
2. window **B**: a real headless chromium (Selenium + chromedriver, as the browser tests) with the page
   of the tornado station — lateness, the page's redraws with new data per second
   (``window.gcs.stats.dataRenders``), the downlink's bytes per second, the browser's CPU;
3. window **B'**: the same browser on the threaded station's page; window **N**: the same browser on the
   tornado station's page again, reniced to 19 (every thread of its processes): what the loop pays for
   the server and the feed alone, the browser's drawing no longer competing for the machine's cores — as
   when the operator watches from another machine, or runs the browser niced on this one;
4. window **I**: 200 idle sockets held open on the tornado station (reopened as the server closes them),
   no page; window **I'**: the same on the threaded one — lateness, and the process's threads;
5. an Abort from the uplink ends the run.

Then a **second run** the same way under ``hil run --rt-priority 20`` (every thread of the host's process
under SCHED_FIFO, the stations' servers included; the browser reset to the normal policy), windows A and
B only: the page attached against nothing attached in that run (docs/runtime-link.md, "Real time on a
busy machine"). Where SCHED_FIFO is not permitted, its rows say why.

Figures: lateness p50/p99 of each window against A (the target: no measurable change), and the tornado
server's against the threaded one's (ours/peer); page updates per second against the 20 Hz target. The
feeds' dropped rows and the machine's load average go into the note: on a shared 2-core machine the
lateness percentiles move with the load.
"""

from __future__ import annotations

import contextlib
import os
import selectors
import shutil
import socket
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
from bench.gcs_threaded_server import ThreadedGcsServer
from hil.gcs import GroundStation
from hil.runtime import RunOptions
from hil.runtime import run as run_scenario
from hil.runtime.observer import RunStart
from hil.scenario import load_scenario

NAME = "gcs"
RATE_HZ = 100.0
RT_PRIORITY = 20
"""The second run's SCHED_FIFO priority (``hil run --rt-priority``)."""
IDLE_SOCKETS = 200
CHROMIUM = os.environ.get("VSCMG_HIL_CHROMIUM", "/usr/bin/chromium")
CHROMEDRIVER = os.environ.get("VSCMG_HIL_CHROMEDRIVER", "/usr/bin/chromedriver")


@dataclass
class _Fanout:
    """The run's observer: both stations' feeds, and the wall time of every control tick (index = the
    scheduler's run number, which is also the index of its lateness sample)."""

    inner: list[Any]
    ticks: list[float] = field(default_factory=list)
    start: RunStart | None = None

    def started(self, start: RunStart) -> None:
        self.start = start
        for o in self.inner:
            o.started(start)

    def row(self, row: Any) -> None:
        for o in self.inner:
            o.row(row)

    def event(self, record: Any) -> None:
        for o in self.inner:
            o.event(record)

    def tick(self, t: float) -> None:
        self.ticks.append(time.monotonic())
        for o in self.inner:
            o.tick(t)

    def finished(self, summary: Any) -> None:
        for o in self.inner:
            o.finished(summary)

    def lateness_us(self, t0: float, t1: float) -> np.ndarray:
        """Control lateness samples (µs) of the ticks between wall times ``t0`` and ``t1``."""
        assert self.start is not None
        control = next(t for t in self.start.scheduler.tasks if t.name == "control")
        samples = control.stats.lateness
        ticks = np.asarray(self.ticks[: samples.size])
        return samples[(ticks >= t0) & (ticks < t1)] * 1e6


class _IdleSockets:
    """``n`` idle TCP connections to ``port``, each reopened as soon as the server closes it (eviction,
    the request deadline), from a thread of this process."""

    def __init__(self, port: int, n: int) -> None:
        self.port, self.n = port, n
        self.stop = threading.Event()
        self.reopened = 0
        self.thread = threading.Thread(target=self._hold, daemon=True)
        self.thread.start()

    def _hold(self) -> None:
        sel = selectors.DefaultSelector()
        for _ in range(self.n):
            sel.register(socket.create_connection(("127.0.0.1", self.port)), selectors.EVENT_READ)
        while not self.stop.is_set():
            for key, _ in sel.select(0.2):
                sock = key.fileobj
                assert isinstance(sock, socket.socket)
                sel.unregister(sock)
                sock.close()
                with contextlib.suppress(OSError):
                    sel.register(socket.create_connection(("127.0.0.1", self.port)), selectors.EVENT_READ)
                    self.reopened += 1
        for key in list(sel.get_map().values()):
            assert isinstance(key.fileobj, socket.socket)
            key.fileobj.close()

    def close(self) -> None:
        self.stop.set()
        self.thread.join(10)


def _measure(window_s: float, world: bool, rt_priority: int | None = None) -> dict[str, Any]:
    """The windows of the module's docstring, in one run; with ``rt_priority`` the run (every thread of
    this process: the stations' servers too) under SCHED_FIFO at that priority, the browser at the
    normal policy, and only windows A and B (``page_rt``)."""
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
        new = stack.enter_context(GroundStation.live(bind="127.0.0.1:0"))
        old = stack.enter_context(GroundStation.live(bind="127.0.0.1:0", server_class=ThreadedGcsServer))
        fanout = _Fanout([new.observer, old.observer])
        options = RunOptions(port="spawn://firmware-sim?" + urlencode(query), phone=phone,
                             duration_s=6 * window_s + 60, out_root=Path(tmp), observer=fanout,
                             rt_priority=rt_priority)  # fmt: skip
        result: dict[str, Any] = {}

        def play() -> None:
            try:
                result["r"] = run_scenario(scenario, options)
            except BaseException as exc:  # raised in this thread by started
                result["error"] = exc

        def started() -> bool:
            if "error" in result:
                raise RuntimeError(f"bench_gcs: the run failed: {result['error']}") from result["error"]
            if "r" in result:
                raise RuntimeError(f"bench_gcs: the run ended early: {result['r'].summary.get('exit')}")
            return any(e.get("kind") == "slew_start" for e in _events(tmp))

        thread = threading.Thread(target=play, daemon=True)
        thread.start()
        _wait(started, 120, "slew start")
        a0 = time.monotonic()
        time.sleep(window_s)
        out["a"] = fanout.lateness_us(a0, time.monotonic())
        browser = _browser()
        stack.callback(browser.quit)
        _normal_policy(browser.service.process.pid)  # started by a thread the run made real-time
        pages = (("rt", new),) if rt_priority is not None else (("new", new), ("old", old), ("niced", new))
        for key, station in pages:
            if key == "niced":
                _renice(browser.service.process.pid, 19)
            browser.get(station.url)
            _wait(lambda: browser.execute_script("return window.gcs.stats.rows") > 0, 30, "page data")
            time.sleep(1.5)  # the history's burst is over
            b0 = time.monotonic()
            cpu0 = _cpu_s(browser.service.process.pid)
            renders0 = browser.execute_script("return window.gcs.stats.dataRenders")
            sent0 = station.hub.stats.bytes_sent
            time.sleep(window_s)
            b1 = time.monotonic()
            renders1 = browser.execute_script("return window.gcs.stats.dataRenders")
            out[f"page_{key}"] = fanout.lateness_us(b0, b1)
            out[f"cpu_{key}"] = (_cpu_s(browser.service.process.pid) - cpu0) / (b1 - b0)
            out[f"updates_{key}"] = (renders1 - renders0) / (b1 - b0)
            out[f"bytes_{key}"] = (station.hub.stats.bytes_sent - sent0) / (b1 - b0)
        browser.get("about:blank")
        for key, station in (("new", new), ("old", old)) if rt_priority is None else ():
            idle = _IdleSockets(station.port, IDLE_SOCKETS)
            time.sleep(1.0)
            i0 = time.monotonic()
            threads = []
            while time.monotonic() < i0 + window_s:
                threads.append(threading.active_count())
                time.sleep(0.25)
            out[f"idle_{key}"] = fanout.lateness_us(i0, time.monotonic())
            out[f"threads_{key}"] = max(threads)
            out[f"reopened_{key}"] = idle.reopened
            idle.close()
            time.sleep(1.0)
        conn = http.client.HTTPConnection("127.0.0.1", new.port, timeout=10)
        headers = {"Content-Type": "application/json", "Authorization": f"token {new.token}"}
        conn.request("POST", "/api/command", body=json.dumps({"command": "abort"}), headers=headers)
        conn.getresponse().read()
        thread.join(60)
        out.update(feed_new=new.stats()["feed"], feed_old=old.stats()["feed"],
                   exit=result["r"].summary.get("exit") if "r" in result else "no result")  # fmt: skip
    return out


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


def _renice(pid: int, niceness: int) -> None:
    """Every thread of ``pid`` and its descendants to ``niceness`` (Linux: a niceness is a thread's; the
    processes they start later inherit it)."""
    for p in _tree(pid):
        with contextlib.suppress(OSError):
            for task in Path(f"/proc/{p}/task").iterdir():
                with contextlib.suppress(OSError):
                    os.setpriority(os.PRIO_PROCESS, int(task.name), niceness)


def _normal_policy(pid: int) -> None:
    """Every thread of ``pid`` and its descendants back to the normal policy (SCHED_OTHER): a browser
    started from a thread under SCHED_FIFO inherited it, and the operator's browser has no such rank."""
    for p in _tree(pid):
        with contextlib.suppress(OSError):
            for task in Path(f"/proc/{p}/task").iterdir():
                with contextlib.suppress(OSError):
                    os.sched_setscheduler(int(task.name), os.SCHED_OTHER, os.sched_param(0))


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


def run(quick: bool) -> list[Result]:
    window_s = 4.0 if quick else 10.0
    load = os.getloadavg()[0]
    cost = _world_cost()
    world = cost < WORLD_BUDGET
    m = _measure(window_s, world)
    rt = _measure_realtime(window_s, world)
    where = "with its world" if world else f"no world (the world needs {cost:.2f} CPU s per s here)"

    def pct(x: np.ndarray, q: float) -> float:
        return float(np.percentile(x, q)) if x.size else float("nan")

    a = m["a"]
    note = (
        f"100 Hz control against spawn://firmware-sim {where}, observed by a tornado station and a threaded "
        f"one at once; windows of {window_s:.0f} s after the slew starts: A {a.size} ticks with nothing "
        f"attached; the page (headless chromium) on tornado {m['page_new'].size} ticks "
        f"({m['cpu_new']:.2f} browser CPU s/s), on threaded {m['page_old'].size} ({m['cpu_old']:.2f}), on "
        f"tornado with the browser niced {m['page_niced'].size} ({m['cpu_niced']:.2f}); "
        f"{IDLE_SOCKETS} idle sockets on tornado {m['idle_new'].size} ticks (at most {m['threads_new']} "
        f"threads in the process, {m['reopened_new']} reopened after the server closed them), on threaded "
        f"{m['idle_old'].size} (at most {m['threads_old']} threads, {m['reopened_old']} reopened); feeds "
        f"dropped {m['feed_new']['dropped_rows']} / {m['feed_old']['dropped_rows']} rows; run exit "
        f"{m['exit']!r}; load average {load:.2f} on {os.cpu_count()} CPUs"
    )
    out = []
    idle = f"{IDLE_SOCKETS} idle sockets"
    for q in (50, 99):
        page, sockets = (
            f"control lateness p{q} at 100 Hz, page attached",
            f"control lateness p{q} at 100 Hz, {idle}",
        )
        out += [
            Result(NAME, f"{page} (tornado)", pct(m["page_new"], q), "us", "same run, nothing attached",
                   pct(a, q), False, note if q == 50 else ""),
            Result(NAME, f"{page} (tornado)", pct(m["page_new"], q), "us", "same run, page on threaded",
                   pct(m["page_old"], q), False),
            Result(NAME, f"{page}, browser niced (tornado)", pct(m["page_niced"], q), "us",
                   "same run, nothing attached", pct(a, q), False,
                   "the same page, its browser at niceness 19: the server and feed alone" if q == 50 else ""),
            Result(NAME, f"{sockets} (tornado)", pct(m["idle_new"], q), "us", "same run, nothing attached",
                   pct(a, q), False),
            Result(NAME, f"{sockets} (tornado)", pct(m["idle_new"], q), "us", f"same run, {idle} on threaded",
                   pct(m["idle_old"], q), False),
        ]  # fmt: skip
    out += _realtime_rows(rt, pct)
    out += [
        Result(NAME, "page updates with new data (tornado)", m["updates_new"], "Hz", "target", 20.0, True,
               "headless chromium, redraws of plots, 3D view and panels that had new rows"),
        Result(NAME, "page updates with new data (tornado)", m["updates_new"], "Hz", "threaded server",
               m["updates_old"], True),
        Result(NAME, "page updates with new data, browser niced (tornado)", m["updates_niced"], "Hz",
               "target", 20.0, True),
        Result(NAME, f"threads in the process, {idle} (tornado)", m["threads_new"], "threads",
               "threaded server", m["threads_old"], False),
        Result(NAME, "downlink on the socket (tornado)", m["bytes_new"] / 1e3, "kB/s", "threaded server",
               m["bytes_old"] / 1e3, False, "SSE: rows with the live columns, events, link statistics"),
    ]  # fmt: skip
    return out


def _measure_realtime(window_s: float, world: bool) -> dict[str, Any] | str:
    """Windows A and B of a second run under ``hil run --rt-priority`` (:data:`RT_PRIORITY`), or why it
    could not be measured here (no privilege for SCHED_FIFO)."""
    from hil.timing.priority import realtime
    from protocol.errors import HilError

    try:
        with realtime(RT_PRIORITY):
            pass
    except HilError as exc:
        return str(exc)
    return _measure(window_s, world, RT_PRIORITY)


def _realtime_rows(rt: dict[str, Any] | str, pct: Any) -> list[Result]:
    """The page-attached rows of the run under SCHED_FIFO: lateness with the page against nothing
    attached, in that run."""
    page = f"control lateness p{{q}} at 100 Hz, page attached, --rt-priority {RT_PRIORITY} (tornado)"
    if isinstance(rt, str):
        return [Result(NAME, page.format(q=99), float("nan"), "us", "same run, nothing attached", None, False,
                       f"not measured: {rt}")]  # fmt: skip
    note = (
        f"a second run, every thread of the host's process under SCHED_FIFO {RT_PRIORITY} (the stations' "
        f"servers too), the browser at the normal policy: A {rt['a'].size} ticks, the page "
        f"{rt['page_rt'].size} ({rt['cpu_rt']:.2f} browser CPU s/s, {rt['updates_rt']:.1f} updates/s)"
    )
    return [
        Result(NAME, page.format(q=q), pct(rt["page_rt"], q), "us", "same run, nothing attached",
               pct(rt["a"], q), False, note if q == 50 else "")
        for q in (50, 99)
    ]  # fmt: skip
