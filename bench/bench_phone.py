"""The live phone receivers (hil.link.sources), each figure next to a peer in the same run:

* SensaGram datagram decode rate (``decode_datagram``: JSON, shape and finiteness checks) next to bare
  ``json.loads`` of the same bytes, the floor any JSON receiver pays;
* the cost of a hostile datagram: ``decode_datagram`` refusing ``b"[" * 3000`` (by its bracket count,
  before the parser, whose RecursionError costs ~0.3 ms) next to decoding a valid one;
* Sensor Logger HTTP Push over loopback (keep-alive POSTs of 50-sample batches through http.client):
  batches/s into :class:`PhonePushServer` (bounded bodies, per-request deadline, connection cap) next to
  the standard library's ``ThreadingHTTPServer`` with a bare handler reading ``Content-Length`` bytes
  into the same decoder: what the guards cost;
* the atheris fuzz harness's inputs/s (``bench/fuzz_phone.py`` in a subprocess).
"""

from __future__ import annotations

import http.client
import json
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

from bench.common import Result, fuzz_rate, rate
from hil.estimation.sensors import SensorKind, SensorSample
from hil.link.sources.phone_push import PhonePushServer, decode_push, encode_push
from hil.link.sources.phone_udp import decode_datagram, encode_datagram
from protocol.errors import InputFormatError

NAME = "phone"
FUZZ = Path(__file__).resolve().parent / "fuzz_phone.py"
BATCH = [SensorSample(1.7e9 + 0.002 * k, SensorKind(k % 3), (0.1 * k, -0.2, 9.8)) for k in range(50)]


def _decode_results(min_time: float) -> list[Result]:
    datagram = encode_datagram(SensorSample(3925657.519, SensorKind.GYR, (0.01, -0.02, 0.003)))
    ours = rate(lambda: decode_datagram(datagram), min_time)
    floor = rate(lambda: json.loads(datagram), min_time)
    deep = b"[" * 3000

    def refuse() -> None:
        try:
            decode_datagram(deep)
        except InputFormatError:
            pass

    hostile = rate(refuse, min_time)
    return [
        Result(NAME, "SensaGram datagram decode", ours, "datagrams/s", "json.loads alone", floor),
        Result(NAME, "hostile datagram refused (b'[' * 3000)", hostile, "datagrams/s",
               "valid datagram decoded", ours, note="refused by the bracket count, before json.loads"),
    ]  # fmt: skip


class _BareHandler(BaseHTTPRequestHandler):
    """The peer: http.server as documented, trusting Content-Length, no deadline, no cap (and Nagle's
    algorithm off, as ours, so that the figure is the guards' cost, not the 40 ms delayed-ACK stall)."""

    protocol_version = "HTTP/1.1"
    disable_nagle_algorithm = True

    def do_POST(self) -> None:  # noqa: N802
        body = self.rfile.read(int(self.headers["Content-Length"]))
        decode_push(body)
        self.send_response(200)
        self.send_header("Content-Length", "2")
        self.end_headers()
        self.wfile.write(b"ok")

    def log_message(self, format: str, *args: object) -> None:  # noqa: A002
        pass


def _post_rate(host: str, port: int, seconds: float) -> float:
    """Keep-alive POSTs of one 50-sample batch per request for ``seconds``: batches/s."""
    body = encode_push(BATCH, 1, "bench", "bench")
    conn = http.client.HTTPConnection(host, port, timeout=5)
    n = 0
    start = time.perf_counter()
    while (elapsed := time.perf_counter() - start) < seconds or n < 20:
        conn.request("POST", "/", body, {"Content-Type": "application/json"})
        response = conn.getresponse()
        response.read()
        if response.status != 200:
            raise RuntimeError(f"push answered {response.status}")
        n += 1
    conn.close()
    return n / elapsed


def _push_results(seconds: float) -> list[Result]:
    with PhonePushServer("http://127.0.0.1:0/") as server:
        host, port = server.url.removeprefix("http://").split("/")[0].split(":")
        ours = _post_rate(host, int(port), seconds)
    bare = ThreadingHTTPServer(("127.0.0.1", 0), _BareHandler)
    bare.daemon_threads = True
    thread = threading.Thread(target=bare.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    try:
        peer = _post_rate("127.0.0.1", bare.server_port, seconds)
    finally:
        bare.shutdown()
        bare.server_close()
    return [
        Result(NAME, "HTTP Push batches (50 samples, keep-alive)", ours, "batches/s",
               "ThreadingHTTPServer, bare handler", peer),
    ]  # fmt: skip


def _fuzz_results(runs: int) -> list[Result]:
    per_sec, inputs = fuzz_rate(FUZZ, runs, "vscmg-fuzz-phone-")
    return [
        Result(NAME, "fuzz datagram+push+body (atheris)", per_sec, "inputs/s",
               note=f"{inputs} inputs without an unhandled exception in this run; "
                    "python bench/fuzz_phone.py -runs=1000000 for the full run"),
    ]  # fmt: skip


def run(quick: bool) -> list[Result]:
    results = _decode_results(0.1 if quick else 1.0)
    results += _push_results(0.3 if quick else 3.0)
    results += _fuzz_results(3_000 if quick else 100_000)
    return results
