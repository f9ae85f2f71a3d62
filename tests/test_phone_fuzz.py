"""Hypothesis fuzzing of everything a phone receiver parses from the network (like the deframer's tests;
``bench/fuzz_phone.py`` is the coverage-guided atheris harness over the same targets):

* the decoders, on arbitrary bytes and on JSON documents shaped like the apps' (right keys, wrong
  types, huge and non-finite numbers, deep nesting): a sample, None, or ``InputFormatError`` — nothing
  else — and every entry of a push accounted for;
* :func:`read_body`, on arbitrary headers and byte streams: at most ``limit`` bytes or a ``BodyError``
  with the status to answer; chunked bodies of any chunking read back exactly;
* both receivers over real loopback sockets, fed mixed valid and hostile messages: each hostile one
  costs itself only, the valid ones all arrive in order, the counters add up, the receiver serves on.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import socket
import time
from email.message import Message

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hil.estimation.sensors import SensorKind, SensorSample
from hil.link.sources.http_guard import BodyError, read_body
from hil.link.sources.phone_push import PhonePushSender, PhonePushServer, decode_push
from hil.link.sources.phone_udp import PhoneUdpReceiver, decode_datagram, encode_datagram
from protocol.errors import InputFormatError

KEYS = ["type", "timestamp", "values", "payload", "name", "time", "x", "y", "z", "messageId"]
NAMES = ["android.sensor.accelerometer", "android.sensor.gyroscope", "android.sensor.magnetic_field",
         "totalacceleration", "gyroscope", "magnetometer", "accelerometer", "gravity",
         "location"]  # fmt: skip
scalars = (
    st.none()
    | st.booleans()
    | st.integers(-(10**400), 10**400)
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.sampled_from(NAMES)
    | st.text(max_size=12)
)
documents = st.recursive(
    scalars,
    lambda inner: (
        st.lists(inner, max_size=5) | st.dictionaries(st.sampled_from(KEYS) | st.text(max_size=5), inner)
    ),
    max_leaves=30,
)
finite = st.floats(-1e4, 1e4, allow_nan=False)
a_sample = st.builds(
    SensorSample,
    st.integers(10**9, 10**16).map(lambda ns: ns / 1e9),
    st.sampled_from(list(SensorKind)),
    st.tuples(finite, finite, finite),
)


def _as_json(doc: object) -> bytes:
    try:
        return json.dumps(doc).encode()
    except ValueError:  # an integer past the digit limit: hand-written, as a peer would
        return b"1" + b"0" * 5000


def _check_datagram(data: bytes) -> None:
    try:
        got = decode_datagram(data, "fuzz")
    except InputFormatError as exc:
        assert exc.path == "fuzz"
        return
    assert got is None or all(math.isfinite(v) for v in (got.t_s, *got.xyz))


def _check_push(data: bytes) -> None:
    try:
        batch = decode_push(data, "fuzz")
        samples, bad, ignored, message_id = batch.samples, batch.bad, batch.ignored, batch.message_id
    except InputFormatError as exc:
        assert exc.path == "fuzz"
        return
    assert all(math.isfinite(v) for s in samples for v in (s.t_s, *s.xyz))
    assert message_id is None or isinstance(message_id, int)
    entries = json.loads(data)["payload"]
    # every entry is a sample, bad or ignored (user acceleration + gravity pairs make one sample per
    # user-acceleration reading; their gravity readings go into those)
    names = [e.get("name", "").lower() if isinstance(e, dict) and isinstance(e.get("name"), str) else None
             for e in entries]  # fmt: skip
    gravity = sum(n == "gravity" for n in names)
    assert len(entries) - gravity <= len(samples) + bad + ignored <= len(entries)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=300) | st.binary(max_size=5000))
def test_any_bytes_decode_to_a_sample_or_an_input_format_error(data):
    _check_datagram(data)
    _check_push(data)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(documents)
def test_json_shaped_like_the_apps_decodes_or_is_refused(doc):
    data = _as_json(doc)
    _check_datagram(data)
    _check_push(data)
    _check_datagram(_as_json({"type": NAMES[1], "timestamp": doc, "values": [doc, 0, 0]}))
    entry = {"name": "gyroscope", "time": doc, "values": {"x": doc, "y": 0, "z": 0}}
    _check_push(_as_json({"messageId": doc, "payload": [entry, doc, {"name": "gravity", "time": 1}]}))


@settings(max_examples=50, deadline=None)
@given(st.integers(1, 100_000), st.sampled_from([b"[", b'{"a":', b'[{"x":']))
def test_deep_nesting_is_refused_not_raised(depth, opener):
    data = opener * depth
    _check_datagram(data)
    _check_push(data)


# =========================================================================== HTTP bodies
def _headers(*pairs: tuple[str, str]) -> Message:
    msg = Message()
    for name, value in pairs:
        msg[name] = value
    return msg


header_value = st.one_of(
    st.integers(-5, 10**6).map(str),
    st.sampled_from(["abc", "+5", "1e3", " 7 ", "0x10", "", "99999999999999999999999", "-0", "٣"]),
    st.text(max_size=8),
)


@settings(max_examples=300, deadline=None)
@given(
    st.lists(st.tuples(st.sampled_from(["Content-Length", "Transfer-Encoding"]), header_value), max_size=3),
    st.binary(max_size=3000),
    st.integers(0, 2000),
)
def test_read_body_returns_at_most_the_limit_or_a_status(pairs, stream, limit):
    pairs = [(n, "chunked" if n == "Transfer-Encoding" and v == "" else v) for n, v in pairs]
    rfile = io.BytesIO(stream)
    try:
        body = read_body(_headers(*pairs), rfile, limit, "fuzz")
    except BodyError as exc:
        assert exc.status in (400, 411, 413, 501) and exc.path == "fuzz"
        return
    assert len(body) <= limit
    assert rfile.tell() <= len(stream)


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=2000), st.lists(st.integers(1, 300), max_size=20), st.integers(0, 2000))
def test_chunked_bodies_of_any_chunking_read_back_exactly(body, cuts, limit):
    parts, pos = [], 0
    for cut in cuts:
        if pos < len(body):
            parts.append(body[pos : pos + cut])
            pos += cut
    parts.append(body[pos:])
    wire = b"".join(b"%x;ext=1\r\n%s\r\n" % (len(p), p) for p in parts if p) + b"0\r\nTrailer: x\r\n\r\nNEXT"
    rfile = io.BytesIO(wire)
    try:
        got = read_body(_headers(("Transfer-Encoding", "chunked")), rfile, limit)
    except BodyError as exc:
        assert exc.status == 413 and len(body) > limit
        return
    assert got == body and rfile.read() == b"NEXT"  # the next request starts right after the trailers


# =========================================================================== through real sockets
hostile = st.one_of(
    st.binary(max_size=200),
    documents.map(_as_json),
    st.integers(2000, 60000).map(lambda n: b"[" * n),
)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.tuples(hostile, a_sample), min_size=1, max_size=20))
def test_the_udp_receiver_survives_any_mix_of_datagrams(pairs):
    with PhoneUdpReceiver("udp://127.0.0.1:0") as receiver:
        host, port = receiver.url.removeprefix("udp://").split(":")
        raw = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        for junk, sample in pairs:
            raw.sendto(junk, (host, int(port)))
            raw.sendto(encode_datagram(sample), (host, int(port)))
        raw.close()
        st_ = receiver.stats
        deadline = time.monotonic() + 10
        while st_.messages + st_.bad_messages < 2 * len(pairs) and time.monotonic() < deadline:
            time.sleep(0.005)
        receiver.check()
        got = [(s.kind, s.xyz) for s in receiver.drain()]
        sent = [(s.kind, s.xyz) for _, s in pairs]
        assert got[-len(sent) :] == sent  # every valid one, in order (junk may itself be a valid event)
        assert st_.messages + st_.bad_messages == 2 * len(pairs)
        assert st_.samples + st_.ignored_entries == st_.messages


request_line = st.sampled_from([b"POST / HTTP/1.1", b"POST /x HTTP/1.0", b"GET / HTTP/1.1", b"PUT / HTTP/1.1",
                                b"POST / HTTP/9.9", b"\x00\xff", b"POST"])  # fmt: skip
header_line = st.one_of(
    st.tuples(
        st.sampled_from([b"Content-Length", b"Transfer-Encoding", b"Connection", b"Expect"]),
        st.sampled_from([b"-1", b"abc", b"5", b"99999999999", b"chunked", b"close", b"100-continue"]),
    ).map(lambda kv: kv[0] + b": " + kv[1]),  # fmt: skip
    st.binary(max_size=40).map(lambda b: b.replace(b"\r", b"").replace(b"\n", b"")),
)


@settings(max_examples=30, deadline=None)
@given(request_line, st.lists(header_line, max_size=4), st.binary(max_size=300))
def test_the_push_server_survives_any_request(line, headers, body):
    with PhonePushServer("http://127.0.0.1:0/", timeout_s=0.5) as server:
        host, port = server.url.removeprefix("http://").split("/")[0].split(":")
        with socket.create_connection((host, int(port)), timeout=3) as conn:
            conn.sendall(line + b"\r\n" + b"".join(h + b"\r\n" for h in headers) + b"\r\n" + body)
            conn.shutdown(socket.SHUT_WR)
            answer = b""
            with contextlib.suppress(TimeoutError, ConnectionResetError):  # the server may close first
                while chunk := conn.recv(65536):
                    answer += chunk
        assert len(answer) < 4096  # a status, or http.server's short error page (HTTP/0.9 style)
        server.check()
        sender = PhonePushSender(server.url)
        sample = SensorSample(1.0, SensorKind.GYR, (0.0, 0.0, 1.0))
        assert sender.send([sample]) and server.drain()[-1:] == [sample]  # still serving
        sender.close()
