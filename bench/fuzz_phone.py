#!/usr/bin/env python
"""Coverage-guided fuzzing (atheris / libFuzzer) of everything a phone receiver parses from the network.

    python bench/fuzz_phone.py -runs=1000000 -print_final_stats=1   # a million inputs, then stats
    python bench/fuzz_phone.py -max_total_time=60 corpus/           # a minute, new inputs to corpus/

Not a pytest test and not a benchmark of its own (it is not named ``bench_*``): ``bench/bench_phone.py``
runs a short burst of it in a subprocess for the inputs/s figure; ``tests/test_phone_fuzz.py`` is the
Hypothesis harness over the same targets. The first byte of each input picks a target, the rest is the
target's input:

* 0 — ``decode_datagram`` (SensaGram over UDP): a sample with finite values, None, or an
  ``InputFormatError``;
* 1 — ``decode_push`` (Sensor Logger's HTTP Push): the same, and every entry of the batch accounted for
  (a sample, bad or ignored);
* 2 — ``read_body`` on a request: the input up to the first blank line is the header block (parsed by
  ``http.client.parse_headers``, as ``http.server`` does), the rest the byte stream; the body is at most
  the limit or a ``BodyError`` carrying 400, 411, 413 or 501.

Any other exception, or a failed check, is a crash: libFuzzer stops and writes the input to
``crash-<sha1>``. The corpus is seeded with the apps' messages (``encode_datagram``, ``encode_push``),
chunked and plain requests, and the inputs of issue 16's findings.
"""

from __future__ import annotations

import http.client
import io
import json
import math
import sys

import atheris
from fuzz_main import run_fuzzer  # beside this script (it runs as one)

with atheris.instrument_imports(include=["hil.link.sources"]):
    from hil.estimation.sensors import SensorKind, SensorSample
    from hil.link.sources.http_guard import BodyError, read_body
    from hil.link.sources.phone_push import decode_push, encode_push
    from hil.link.sources.phone_udp import decode_datagram, encode_datagram
    from protocol.errors import InputFormatError

TARGET_DATAGRAM, TARGET_PUSH, TARGET_BODY = 0, 1, 2
LIMIT = 4096  # bytes: read_body's cap in the body target (small, so the fuzzer reaches it)


def _finite(sample: SensorSample) -> bool:
    return all(math.isfinite(v) for v in (sample.t_s, *sample.xyz))


def fuzz_datagram(data: bytes) -> None:
    try:
        got = decode_datagram(data, "fuzz")
    except InputFormatError:
        return
    assert got is None or _finite(got), f"a sample with non-finite values: {got!r}"


def fuzz_push(data: bytes) -> None:
    try:
        batch = decode_push(data, "fuzz")
        samples, bad, ignored = batch.samples, batch.bad, batch.ignored
    except InputFormatError:
        return
    assert all(_finite(s) for s in samples), "a sample with non-finite values"
    entries = len(json.loads(data)["payload"])
    assert len(samples) + bad + ignored <= entries, "more counted than the batch holds"


def fuzz_body(data: bytes) -> None:
    head, _, stream = data.partition(b"\r\n\r\n")
    try:
        headers = http.client.parse_headers(io.BytesIO(head + b"\r\n\r\n"))
    except http.client.HTTPException:
        return  # http.server answers these itself (431, 400) before a body is read
    rfile = io.BytesIO(stream)
    try:
        body = read_body(headers, rfile, LIMIT, "fuzz")
    except BodyError as exc:
        assert exc.status in (400, 411, 413, 501), f"status {exc.status}"
        return
    assert len(body) <= LIMIT, f"a body of {len(body)} bytes past the {LIMIT} cap"


TARGETS = {TARGET_DATAGRAM: fuzz_datagram, TARGET_PUSH: fuzz_push, TARGET_BODY: fuzz_body}


def test_one_input(data: bytes) -> None:
    if not data:
        return
    TARGETS[data[0] % len(TARGETS)](data[1:])


# =========================================================================== seed corpus
def seeds() -> list[bytes]:
    """The apps' messages, requests around them, and the inputs of issue 16's findings."""
    samples = [SensorSample(3925657.519043709 + 0.01 * k, kind, (0.31, -0.97, 10.04)) for k, kind in
               enumerate(SensorKind)]  # fmt: skip
    push = encode_push(samples, 12, "session", "device")
    out = [bytes([TARGET_DATAGRAM]) + encode_datagram(s) for s in samples]
    out += [bytes([TARGET_DATAGRAM]) + b"[" * 3000, bytes([TARGET_PUSH]) + b"[" * 60000]
    out.append(bytes([TARGET_PUSH]) + push)
    chunked = b"".join(b"%x\r\n%s\r\n" % (len(p), p) for p in (push[:40], push[40:])) + b"0\r\n\r\n"
    for head, body in (
        (f"Content-Length: {len(push)}", push),
        ("Content-Length: -1", push),
        ("Content-Length: abc", push),
        ("Transfer-Encoding: chunked", chunked),
        ("Content-Length: 5\r\nContent-Length: 6", push),
    ):
        out.append(bytes([TARGET_BODY]) + f"Host: x\r\n{head}\r\n\r\n".encode() + body)
    return out


def main(argv: list[str]) -> None:
    run_fuzzer(argv, seeds(), test_one_input, "vscmg-fuzz-phone-seeds-")


if __name__ == "__main__":
    sys.setrecursionlimit(1000)
    main(sys.argv)
