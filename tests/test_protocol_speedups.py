"""The C extension (``protocol._speedups``) against the pure-Python reference it stands in for, and the
fallback: COBS, CRC-16 and the fused frame seal/unseal on random data and on the test vectors, and the
codec running with the extension switched off (``PROTOCOL_PURE=1``) or missing (no compiler at install).

The extension is built by ``pip install`` wherever there is a C compiler (every machine of this project
has gcc), so these tests require it: a build that silently failed would otherwise leave the fast path
untested behind the fallback.
"""

from __future__ import annotations

import binascii
import json
import os
import subprocess
import sys

import hypothesis.strategies as st
import pytest
from hypothesis import given, settings
from test_protocol_strategies import wire_frames

from hil.scenario.paths import FIXTURES
from protocol import _speedups as native  # type: ignore[attr-defined]
from protocol import cobs, speedups
from protocol.crc import crc16_ccitt_false
from protocol.errors import FrameError
from protocol.frame import MAX_FRAME, MIN_FRAME

VECTORS = json.loads((FIXTURES / "protocol_vectors.json").read_text(encoding="utf-8"))


def _reference_decode(data: bytes) -> bytes | None:
    try:
        return cobs.decode(data)
    except FrameError:
        return None


def test_the_codec_runs_on_the_extension_here():
    assert speedups.NATIVE, "protocol._speedups was not built, or PROTOCOL_PURE is set"
    assert speedups.seal is native.seal and speedups.unseal is native.unseal


# =========================================================================== C against the reference
@given(st.binary(max_size=1200) | st.binary(max_size=1200).map(lambda b: b.replace(b"\x00", b"\x01")))
def test_cobs_encode_is_the_reference_byte_for_byte(data):
    assert native.cobs_encode(data) == cobs.encode(data)
    assert native.cobs_encode(bytearray(data)) == cobs.encode(data)  # any bytes-like object


@given(st.binary(max_size=800) | st.binary(max_size=800).map(lambda b: b.replace(b"\x00", b"\xff")))
def test_cobs_decode_agrees_with_the_reference_on_anything(data):
    """Valid or not: the same bytes, or None exactly where the reference raises."""
    assert native.cobs_decode(data) == _reference_decode(data)


@given(st.binary(max_size=1200))
def test_cobs_round_trips_through_c(data):
    assert native.cobs_decode(native.cobs_encode(data)) == data


@given(st.binary(max_size=600), st.integers(0, 0xFFFF))
def test_crc_is_the_reference(data, value):
    assert native.crc16(data) == crc16_ccitt_false(data) == binascii.crc_hqx(data, 0xFFFF)
    assert native.crc16(data, value) == crc16_ccitt_false(data, value)


def test_crc_and_unseal_refuse_bad_arguments_with_python_errors():
    with pytest.raises(ValueError):
        native.crc16(b"", 0x10000)
    with pytest.raises(TypeError):
        native.crc16("text")
    with pytest.raises(ValueError):
        native.unseal(b"\x01", 1, 10)
    with pytest.raises(TypeError):
        native.unseal(b"\x01", 6)


@given(st.binary(min_size=MIN_FRAME - 2, max_size=MAX_FRAME - 2))
def test_seal_is_the_reference_and_unseal_inverts_it(body):
    wire = native.seal(body)
    assert wire == speedups.seal_reference(body)
    assert wire.endswith(b"\x00") and 0 not in wire[:-1]
    assert native.unseal(wire[:-1], MIN_FRAME, MAX_FRAME) == body
    assert speedups.unseal_reference(wire[:-1], MIN_FRAME, MAX_FRAME) == body


@settings(max_examples=300)
@given(wire_frames(), st.data())
def test_unseal_agrees_with_the_reference_on_damaged_frames(frame, data):
    """Flipped bytes, cut or extended chunks: C and reference take or refuse the same chunks."""
    chunk = bytearray(frame[3][:-1])
    for _ in range(data.draw(st.integers(0, 3))):
        i = data.draw(st.integers(0, len(chunk) - 1))
        chunk[i] ^= data.draw(st.integers(1, 255))
    chunk = bytes(chunk[: data.draw(st.integers(0, len(chunk)))]) + data.draw(st.binary(max_size=3))
    for lo, hi in ((MIN_FRAME, MAX_FRAME), (2, 8)):
        assert native.unseal(chunk, lo, hi) == speedups.unseal_reference(chunk, lo, hi)


# =========================================================================== on the vectors
def test_c_passes_the_cobs_and_crc_vectors():
    for v in VECTORS["cobs"]:
        decoded, encoded = bytes.fromhex(v["decoded_hex"]), bytes.fromhex(v["encoded_hex"])
        assert native.cobs_encode(decoded) == encoded
        assert native.cobs_decode(encoded) == decoded
    for v in VECTORS["crc"]:
        assert native.crc16(bytes.fromhex(v["data_hex"])) == int(v["crc"], 16)


def test_c_seals_and_unseals_every_frame_vector():
    for v in VECTORS["frames"]:
        frame, wire = bytes.fromhex(v["frame_hex"]), bytes.fromhex(v["wire_hex"])
        assert native.seal(frame[:-2]) == wire, v["name"]
        assert native.unseal(wire[:-1], MIN_FRAME, MAX_FRAME) == frame[:-2], v["name"]


def test_c_refuses_exactly_the_bad_vectors_the_reference_refuses():
    """The COBS, CRC and size failures are refused (None); the others unseal and fail later."""
    refused = {"cobs", "crc", "too_short", "too_long"}
    for v in VECTORS["bad_frames"]:
        chunk = bytes.fromhex(v["wire_hex"]).split(b"\x00")[0]
        got = native.unseal(chunk, MIN_FRAME, MAX_FRAME)
        assert got == speedups.unseal_reference(chunk, MIN_FRAME, MAX_FRAME), v["name"]
        assert (got is None) == (v["reason"] in refused), v["name"]


# =========================================================================== the fallback
def _python(code: str, **env: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-c", code],
        env={**os.environ, **env},
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )


_ON_THE_REFERENCE = """
import sys
{prelude}
from protocol import speedups, cobs
from protocol.__main__ import main
from protocol.frame import decode_stream, encode_frame
from protocol.messages import Heartbeat
assert not speedups.NATIVE, "expected the pure-Python reference"
assert speedups.seal is speedups.seal_reference and speedups.cobs_encode is cobs.encode
wire = encode_frame(Heartbeat(time_ms=5), 9) + b"\\x01\\x02\\x00"
events = decode_stream(wire)
assert events[0].message == Heartbeat(time_ms=5) and events[1].reason.value == "cobs", events
sys.exit(main(["vectors", "--check"]))
"""


@pytest.mark.parametrize(
    ("how", "prelude", "env"),
    [
        ("PROTOCOL_PURE=1", "", {"PROTOCOL_PURE": "1"}),
        ("extension missing", "sys.modules['protocol._speedups'] = None  # as if never built", {}),
    ],
)
def test_the_codec_passes_the_vectors_on_the_pure_python_reference(how, prelude, env):
    proc = _python(_ON_THE_REFERENCE.format(prelude=prelude), **env)
    assert proc.returncode == 0, f"{how}: {proc.stdout}{proc.stderr}"
    assert "up to date" in proc.stdout


def test_protocol_pure_0_keeps_the_extension():
    proc = _python("from protocol import speedups; assert speedups.NATIVE", PROTOCOL_PURE="0")
    assert proc.returncode == 0, proc.stderr
