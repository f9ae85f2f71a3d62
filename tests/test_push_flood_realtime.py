"""A running real-time host, its phone on HTTP Push, and a peer on the same network pushing legal 4 MB
batches of 50 000 plausible readings: control keeps its schedule, every reading is counted. Three
processes as a user would have them: firmware-sim with its world on a pty (streaming its phone to the host
as Sensor Logger does), the host (``hil.runtime.run``, in this process), and the peer (a process of its
own, as it would be on the network). The peer poses as the phone (its session and device ids): the
receiver follows one phone, and another's pushes would be dropped before they reach the queue.

Regression test for issue 26, finding 4: three such pushes made the control task up to 456 ms late
(93 overruns) and put the board in failsafe three times, and the run still said it completed.

**What is the push's fault.** This machine runs other work beside the tests (a campaign and other test
sessions on both cores, CPU pressure ~90 %): without any push, runs here were up to 145 ms late and the
board failed safe in one run of three — the host's process or the board's left without the CPU for a few
hundred ms, the board's pty then not read so that the host's writes wait, the host's own garbage
collector (0.1-0.5 s collections of its heap). With the fix, runs with these pushes were 0.01-1.5 s late
with 0 to 16 failsafes, depending on the load; without it, 0.12-1.07 s with 0 to 13. Lateness and
failsafes say as much about the machine as about the push, so they are reported, not asserted. What is
asserted is what the push costs the control thread itself while the pushes land (from the first to
:data:`SETTLE_S` after the last answer): its CPU time between two ticks (``time.thread_time``, which no
scheduling delay inflates), less what the garbage collector took of it, stays under
:data:`TICK_CPU_LIMIT_S`. Measured here: at most 2.4 ms with the fix; 87-114 ms without (the 50 000
readings went to the estimator in one call). That the push's decoding is not in the host's process at all is
``test_phone_hostile.py::test_a_4_mib_push_is_decoded_in_a_process_of_its_own_and_every_reading_counted``.
"""

from __future__ import annotations

import gc
import math
import signal
import subprocess
import sys
import threading
import time
from typing import Any

import pytest

from hil.link.sources.stream import MAX_QUEUE
from hil.runtime import RunOptions, run
from hil.runtime.host import Host
from hil.scenario import load_scenario

READINGS = 50_000
PUSHES = 3
TICK_CPU_LIMIT_S = 0.02  # the control thread's CPU between two control ticks (a period: 20 ms)
SETTLE_S = 1.0  # after the last push is answered, what it left is drained (4096 samples: 64 ticks, 0.32 s)


# The peer: told the phone stream's newest time stamp, it stamps its readings there, 0.5 us apart (the
# whole push spans 25 ms of the phone's clock: a flood of plausible readings, which the host's admission
# drops as a burst or as past — not so spread out that it would take them for the phone's clock having
# moved, whose handling is the estimator's business, not the network's). It runs niced: on the network it
# would be a machine of its own, not a share of the two cores the processes under test run on.
PEER = r"""
import http.client, json, os, sys, time
os.nice(19)
port, n, pushes = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
names = ["gyroscope", "totalacceleration", "magnetometer"]
values = {"gyroscope": {"x": 0.01, "y": -0.02, "z": 0.003},
          "totalacceleration": {"x": 0.1, "y": 0.2, "z": 9.8},
          "magnetometer": {"x": 20.5, "y": -5.25, "z": -40.5}}
entries = [json.dumps({"name": names[i % 3], "time": 1, "values": values[names[i % 3]]},
                      separators=(",", ":")).split('"time":1') for i in range(n)]
print("ready", flush=True)
t0_ns = round(float(sys.stdin.readline()) * 1e9)
for k in range(pushes):
    payload = ",".join(f'{a}"time":{t0_ns + 500 * i}{b}' for i, (a, b) in enumerate(entries))
    head = '{"messageId":%d,"sessionId":"vscmg-hil-sim","deviceId":"simulated-phone","payload":[' % (1000 + k)
    body = (head + payload + "]}").encode()
    try:
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
        conn.request("POST", "/", body, {"Content-Type": "application/json"})
        answer = conn.getresponse()
        answer.read()
        print(answer.status, len(body), time.monotonic(), flush=True)
        conn.close()
    except OSError as exc:
        print("error", len(body), time.monotonic(), type(exc).__name__, flush=True)
    time.sleep(0.3)
"""


class Collections:
    """The garbage collector's runs in one thread (monotonic intervals), through ``gc.callbacks``: a run
    is work of the interpreter's, charged to whichever thread's allocation triggered it."""

    def __init__(self) -> None:
        self.runs: list[tuple[float, float]] = []
        self.thread: int | None = None  # the thread whose collections are noted (set from that thread)
        self._start = 0.0
        gc.callbacks.append(self._note)

    def _note(self, phase: str, info: dict[str, Any]) -> None:
        if threading.get_ident() != self.thread:
            return
        if phase == "start":
            self._start = time.thread_time()
        else:
            self.runs.append((self._start, time.thread_time()))

    def cpu_between(self, start: float, end: float) -> float:
        """The thread's CPU time (s) spent collecting between two of its ``thread_time`` readings."""
        return sum(b - a for a, b in self.runs if a >= start and b <= end)

    def close(self) -> None:
        gc.callbacks.remove(self._note)


@pytest.mark.slow
def test_4_mb_pushes_into_a_running_host_do_not_stall_control(tmp_path, push_port):
    url = f"http://127.0.0.1:{push_port}/"
    link = tmp_path / "board"
    sim = subprocess.Popen(
        [sys.executable, "-m", "firmware_sim", "--world", "cubesat-1u", "--link", str(link), "--phone", url],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    peer = subprocess.Popen(
        [sys.executable, "-c", PEER, str(push_port), str(READINGS), str(PUSHES)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    told: list[float] = []
    ticks: list[tuple[float, float]] = []  # after each control tick: monotonic s, the thread's CPU s

    def progress(host: Host, t: float) -> None:
        """In the control thread, after each tick: the times; once the phone streams, the peer is told
        the phone's clock (a pipe write)."""
        collections.thread = threading.get_ident()
        ticks.append((time.monotonic(), time.thread_time()))
        if not told and t >= 0.5 and math.isfinite(host.guard.newest):
            assert peer.stdin is not None
            peer.stdin.write(f"{host.guard.newest!r}\n")
            peer.stdin.flush()
            told.append(ticks[-1][0])

    collections = Collections()
    try:
        assert peer.stdout is not None and peer.stdout.readline() == "ready\n"  # its entries built
        deadline = time.monotonic() + 60
        while not link.exists():
            assert sim.poll() is None and time.monotonic() < deadline, "firmware-sim did not start"
            time.sleep(0.05)
        scenario = load_scenario("cubesat-1u")
        options = RunOptions(port=str(link), phone=url, duration_s=8.0, out_root=tmp_path, progress=progress)
        result = run(scenario, options)
        answers, _ = peer.communicate(timeout=120)
    finally:
        collections.close()
        sim.send_signal(signal.SIGINT)
        sim.wait(timeout=30)
        if peer.poll() is None:
            peer.kill()
            peer.wait()
    s = result.summary
    assert told, "the phone never streamed"
    lines = [line.split() for line in answers.splitlines()]  # one per push: status, size, time
    assert len(lines) == PUSHES and all(int(size) > 3_900_000 for _, size, *_ in lines)  # 4 MB each
    ok = sum(line[0] == "200" for line in lines)
    assert ok >= 1, f"no push was taken during the run: {answers}"
    until = max(float(line[2]) for line in lines) + SETTLE_S
    busy = []
    for (a, cpu_a), (b, cpu_b) in zip(ticks, ticks[1:], strict=False):
        own = cpu_b - cpu_a - collections.cpu_between(cpu_a, cpu_b)
        if told[0] <= b and a <= until and own > TICK_CPU_LIMIT_S:
            busy.append(f"{own:.3f} s at {a - told[0]:+.2f} s")
    seen = f"the summary's control task: {s['tasks']['control']}, {s['failsafe_events']} failsafe(s)"
    assert not busy, f"the control thread's own work between two ticks: {busy}; {seen}"
    phone = s["phone"]
    assert phone["samples"] >= ok * READINGS  # every reading of every push taken is counted ...
    assert phone["overflow"] >= ok * (READINGS - MAX_QUEUE)  # ... those beyond what it holds dropped
    # nothing was malformed; on a loaded machine a push may wait past the decoder's deadline (503, counted)
    assert phone["bad_messages"] == 0 or "not decoded" in phone["last_error"], phone
