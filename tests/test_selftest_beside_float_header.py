"""``hil selftest --vectors FILE`` beside a vector whose frame header is not an integer: a ``seq`` of 1.5 or
``flags`` of 0.0 passed the encoder's range check and reached ``struct``, whose ``struct.error`` was a
traceback out of the selftest. The header's bytes are held to the rule of every u8 field (an int, not a
bool, 0..255: a :class:`FieldRangeError` naming the field), and a vector whose check raises anything at all
is that vector's failed line in the report."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from protocol.errors import FieldRangeError
from protocol.frame import Flags, decode_frame, encode_frame
from protocol.messages import Arm
from protocol.vectors.check import check_document

VECTORS = Path(__file__).resolve().parents[1] / "fixtures" / "protocol_vectors.json"


@pytest.mark.parametrize(
    ("seq", "flags", "field"),
    [
        (1.5, 0, "seq"),
        (True, 0, "seq"),
        (1, 0.0, "flags"),
        (1, False, "flags"),
        ("1", 0, "seq"),
        (1, None, "flags"),
    ],
)
def test_a_header_byte_that_is_no_integer_is_a_field_range_error_naming_it(seq, flags, field):
    with pytest.raises(FieldRangeError) as caught:
        encode_frame(Arm(), seq, flags)
    assert (caught.value.message_name, caught.value.field) == ("header", field)


def test_integer_header_bytes_and_flags_still_encode():
    frame = decode_frame(encode_frame(Arm(), 255, Flags.RETRANSMIT)[:-1])
    assert (frame.seq, frame.flags) == (255, Flags.RETRANSMIT)


def _document(key: str, value: object) -> dict:
    document = json.loads(VECTORS.read_text())
    document["frames"][0][key] = value
    return document


@pytest.mark.parametrize(("key", "value"), [("seq", 1.5), ("flags", 0.0), ("seq", True), ("flags", [0])])
def test_the_checker_reports_the_vector_instead_of_raising(key, value):
    results = check_document(_document(key, value))
    failed = [r for r in results if not r.ok]
    assert [r.name for r in failed] == ["Hello/typical"]
    assert sum(r.ok for r in results) == len(results) - 1


@pytest.mark.parametrize(
    ("key", "value", "said"), [("seq", 1.5, "header.seq = 1.5"), ("flags", 0.0, "flags")]
)
def test_hil_selftest_fails_the_vector_with_one_line(tmp_path, key, value, said):
    path = tmp_path / "vectors.json"
    path.write_text(json.dumps(_document(key, value)))
    done = subprocess.run(
        [sys.executable, "-m", "hil", "selftest", "--vectors", str(path)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    out = done.stdout + done.stderr
    assert done.returncode == 1 and "Traceback" not in out, out[-2000:]
    assert "FAIL Hello/typical" in out and said in out
