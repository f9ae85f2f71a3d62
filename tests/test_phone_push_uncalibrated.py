"""Sensor Logger's HTTP Push of its raw ("Uncalibrated") sensor types — ``gyroscopeuncalibrated``,
``magnetometeruncalibrated``, ``accelerometeruncalibrated``, pushed when the user enables them — was
ignored whole: a phone pushing only those streamed nothing the host used. Now each stands in for its
sensor while the stream has not sent that sensor's calibrated type, and is ignored and counted from the
first calibrated reading on (the app always pushes the calibrated ones beside them), as SensaGram's
uncalibrated types over UDP and the CSV export's ``…Uncalibrated.csv`` files are; never two sensors'
readings interleaved as one. Through a real receiver on loopback HTTP, inline and in the decoder process."""

from __future__ import annotations

import http.client
import json

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.estimation.sensors import SensorKind
from hil.link.sources.phone_push import PhonePushServer

GYR, ACC, MAG = SensorKind.GYR, SensorKind.ACC, SensorKind.MAG
CAL = {GYR: "gyroscope", ACC: "totalacceleration", MAG: "magnetometer"}
RAW = {GYR: "gyroscopeuncalibrated", ACC: "accelerometeruncalibrated", MAG: "magnetometeruncalibrated"}
VALUE = {  # (calibrated z, raw z): told apart by their values
    GYR: (0.01, 0.02),
    ACC: (9.9, 9.6),
    MAG: (-40.0, -55.0),
}


def batch(message_id: int, t0_ns: int, names: list[str], pad: int = 0, raw_acc_in_g: bool = False) -> bytes:
    """A push of two readings 5 ms apart of each of ``names``; ``pad`` readings of an unused sensor make
    it large (the decoder process's path)."""
    payload = []
    for k in range(2):
        t = t0_ns + 5_000_000 * k
        for name in names:
            kind, raw = next((kind, name == RAW[kind]) for kind in CAL if name in (CAL[kind], RAW[kind]))
            z = VALUE[kind][raw]
            if raw and kind is ACC and raw_acc_in_g:
                z = z / 9.80665
            values = {"x": 0.0, "y": 0.0, "z": z}
            if raw:
                values |= {"xBias": 0.5, "yBias": 0.5, "zBias": 0.5}  # unread, as the CSV's bias columns
            payload.append({"name": name, "time": t, "values": values})
    payload += [{"name": "light", "time": t0_ns, "values": {"x": 1.0, "y": 0.0, "z": 0.0}}] * pad
    return json.dumps(
        {"messageId": message_id, "sessionId": "s", "deviceId": "d", "payload": payload}
    ).encode()


def push_all(bodies: list[bytes]):
    """The bodies pushed in turn to a fresh receiver: what it delivered, and its stats."""
    with PhonePushServer("http://127.0.0.1:0/") as server:
        host, port = server.url.split("//")[1].split("/")[0].split(":")
        conn = http.client.HTTPConnection(host, int(port), timeout=30)
        for body in bodies:
            conn.request("POST", "/", body, {"Content-Type": "application/json"})
            resp = conn.getresponse()
            assert resp.status == 200, resp.read()
            resp.read()
        conn.close()
        return server.drain(), server.stats


@pytest.mark.parametrize("pad", [0, 2000], ids=["inline", "decoder process"])
@pytest.mark.parametrize("in_g", [False, True], ids=["m/s2", "g"])
def test_a_phone_pushing_only_raw_types_streams_every_sensor(pad, in_g):
    bodies = [batch(i + 1, 10**18 + i * 10**8, list(RAW.values()), pad, in_g) for i in range(3)]
    samples, stats = push_all(bodies)
    for kind in CAL:
        got = [s.xyz[2] for s in samples if s.kind is kind]
        assert got == pytest.approx([VALUE[kind][1]] * 6, rel=1e-12), kind
    assert stats.ignored_entries == pad * 3


@pytest.mark.parametrize("pad", [0, 2000], ids=["inline", "decoder process"])
def test_raw_types_beside_the_calibrated_ones_are_ignored_and_counted(pad):
    names = [*CAL.values(), *RAW.values()]
    samples, stats = push_all([batch(i + 1, 10**18 + i * 10**8, names, pad) for i in range(3)])
    for kind in CAL:
        assert [s.xyz[2] for s in samples if s.kind is kind] == [VALUE[kind][0]] * 6
    assert stats.ignored_entries == 3 * (3 * 2 + pad)


@settings(max_examples=30, deadline=None)
@given(st.lists(st.tuples(st.booleans(), st.booleans()), min_size=1, max_size=8))
def test_a_sensor_s_raw_type_stands_in_only_until_its_calibrated_type_is_heard(batches):
    """Model: a batch's raw gyroscope readings are used while no calibrated gyroscope reading has been
    pushed, in this batch or before; the calibrated ones always; every other reading is counted."""
    bodies, expected, ignored, heard = [], [], 0, False
    for i, (cal, raw) in enumerate(batches):
        names = [name for name, on in ((CAL[GYR], cal), (RAW[GYR], raw)) if on]
        bodies.append(batch(i + 1, 10**18 + i * 10**8, names))
        heard |= cal
        expected += [VALUE[GYR][0]] * 2 * cal
        if raw and heard:
            ignored += 2
        elif raw:
            expected += [VALUE[GYR][1]] * 2
    samples, stats = push_all(bodies)
    assert [s.xyz[2] for s in samples if s.kind is GYR] == expected
    assert stats.ignored_entries == ignored
