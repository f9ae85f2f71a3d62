"""The canonical test vectors: the committed file is what the code generates, the codec passes every
vector in both directions, and the checker catches a codec or a file that disagrees."""

from __future__ import annotations

import copy
import json
import os
from pathlib import Path

import pytest

from hil.cli import main as hil_main
from hil.scenario.paths import FIXTURES
from protocol import cobs
from protocol.__main__ import main as protocol_main
from protocol.frame import BadFrame, BadFrameReason, Deframer, Frame, encode_frame
from protocol.messages import BY_ID, CATALOGUE, SCHEMA_HASH, ActuatorSetpoint, Telemetry
from protocol.vectors import (
    FORMAT,
    build_document,
    check_document,
    check_vectors,
    from_json,
    render_json,
    to_json,
)

VECTORS = FIXTURES / "protocol_vectors.json"


@pytest.fixture(scope="module")
def document():
    return json.loads(VECTORS.read_text(encoding="utf-8"))


def test_committed_vectors_are_what_the_code_generates():
    assert VECTORS.read_text(encoding="utf-8") == render_json(build_document()), (
        "fixtures/protocol_vectors.json is stale: run python -m protocol vectors --write"
    )
    assert protocol_main(["vectors", "--check"]) == 0


def test_the_codec_passes_every_vector_both_ways():
    results = check_vectors(VECTORS)
    failed = [r for r in results if not r.ok]
    assert failed == []
    names = {r.name for r in results}
    assert {"header", "messages", "coverage/messages", "coverage/bad_reasons"} <= names


def test_the_vectors_cover_every_message_and_every_bad_reason(document):
    assert document["format"] == FORMAT and document["schema_hash"] == f"0x{SCHEMA_HASH:08x}"
    assert {v["message"] for v in document["frames"]} == {cls.__name__ for cls in CATALOGUE}
    assert {v["reason"] for v in document["bad_frames"]} == {r.value for r in BadFrameReason}
    assert len({v["name"] for v in document["frames"]}) == len(document["frames"])  # names are unique
    for v in document["frames"]:
        assert v["wire_hex"].endswith("00") and "00" not in _bytes_pairs(v["wire_hex"][:-2])


def _bytes_pairs(hex_text: str) -> list[str]:
    return [hex_text[i : i + 2] for i in range(0, len(hex_text), 2)]


def test_json_field_form_round_trips_and_is_strict():
    msg = ActuatorSetpoint(units=())
    values = to_json(Telemetry())
    assert from_json(Telemetry, values) == Telemetry()
    bad_enum = dict(values, state={"name": "ARMED", "value": 1})  # name and value disagree
    with pytest.raises(ValueError, match=r"Telemetry\.state"):
        from_json(Telemetry, bad_enum)
    with pytest.raises(ValueError, match="unknown field"):
        from_json(Telemetry, dict(values, extra=1))
    with pytest.raises(ValueError, match=r"units\[0\]"):
        from_json(ActuatorSetpoint, dict(to_json(msg), units=[{"gimbal": "x", "rotor_speed": 0.0}]))


# =========================================================================== the checker can fail
def _mutated(document, mutate):
    doc = copy.deepcopy(document)
    mutate(doc)
    return {r.name: r for r in check_document(doc)}


def test_a_changed_wire_byte_fails_that_vector(document):
    def flip(doc):
        v = doc["frames"][0]
        wire = bytearray.fromhex(v["wire_hex"])
        wire[3] ^= 0x40
        v["wire_hex"] = wire.hex()

    results = _mutated(document, flip)
    name = document["frames"][0]["name"]
    assert not results[name].ok and "encode gave" in results[name].detail
    assert sum(not r.ok for r in results.values()) == 1


def test_a_changed_field_value_fails_that_vector(document):
    index = next(i for i, v in enumerate(document["frames"]) if v["message"] == "Telemetry")

    def change(doc):
        doc["frames"][index]["fields"]["battery_mv"] += 1

    results = _mutated(document, change)
    assert not results[document["frames"][index]["name"]].ok


def test_a_wrong_expected_reason_fails_that_bad_vector(document):
    def change(doc):
        doc["bad_frames"][0]["reason"] = "version"

    results = _mutated(document, change)
    assert not results[document["bad_frames"][0]["name"]].ok


def test_another_schema_or_a_missing_message_is_reported(document):
    def change(doc):
        doc["schema_hash"] = "0x00000000"
        doc["frames"] = [v for v in doc["frames"] if v["message"] != "Log"]

    results = _mutated(document, change)
    assert not results["header"].ok and "schema_hash" in results["header"].detail
    assert not results["coverage/messages"].ok and "Log" in results["coverage/messages"].detail


def test_a_malformed_vector_is_a_failed_result_not_a_crash(document):
    def change(doc):
        doc["frames"][1]["fields"] = "nonsense"
        doc["frames"][2]["wire_hex"] = "zz"
        del doc["bad_frames"][1]["wire_hex"]

    results = _mutated(document, change)
    failed = [r for r in results.values() if not r.ok]
    assert len(failed) == 3 and all("malformed vector" in r.detail for r in failed)


def test_unreadable_files_are_one_failed_result(tmp_path):
    missing = check_vectors(tmp_path / "nope.json")
    assert len(missing) == 1 and not missing[0].ok and "cannot read" in missing[0].detail
    (tmp_path / "bad.json").write_text("{not json")
    assert not check_vectors(tmp_path / "bad.json")[0].ok
    (tmp_path / "other.json").write_text("[1, 2]")
    assert not check_vectors(tmp_path / "other.json")[0].ok


# =========================================================================== the command lines
def test_hil_selftest_passes_on_the_committed_vectors(capsys):
    assert hil_main(["selftest"]) == 0
    out = capsys.readouterr().out
    assert f"schema hash {SCHEMA_HASH:#010x}" in out and "FAIL" not in out


def test_hil_selftest_fails_on_a_tampered_file(tmp_path, capsys, document):
    doc = copy.deepcopy(document)
    doc["frames"][0]["seq"] = (doc["frames"][0]["seq"] + 1) % 256
    path = tmp_path / "vectors.json"
    path.write_text(json.dumps(doc))
    assert hil_main(["selftest", "--vectors", str(path)]) == 1
    assert f"FAIL {doc['frames'][0]['name']}" in capsys.readouterr().out


def _hostile_vectors(tmp_path: Path) -> dict[str, str]:
    """Paths that are no vectors file: (path, what the error says)."""
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100_000 + "]" * 100_000)
    huge_int = tmp_path / "bigint.json"
    huge_int.write_text('{"a": ' + "9" * 5000 + "}")
    empty = tmp_path / "empty.json"
    empty.write_text("")
    fifo = tmp_path / "fifo.json"
    os.mkfifo(fifo)
    return {
        "/dev/zero": "character device",
        str(deep): "nested deeper",
        str(huge_int): "digits",
        str(empty): "not JSON",
        str(tmp_path): "Is a directory",
        str(tmp_path / "nope.json"): "no such file",
        str(fifo): "",  # hil reads a FIFO as it comes (a shell's <(...)); the library refuses it
    }


def test_hil_selftest_on_a_file_that_is_no_vectors_file_is_one_line_and_status_2(tmp_path, capsys):
    """``/dev/zero`` grew until the machine's memory ran out, a JSON nested 100 000 deep or an integer of
    5 000 digits was a traceback, a directory or an empty file "FAIL" with status 1: each is now a typed
    error naming the file (status 2); the library's check_vectors one failed result, never an exception."""
    for path, said in _hostile_vectors(tmp_path).items():
        if said:
            assert hil_main(["selftest", "--vectors", path]) == 2, path
            err = capsys.readouterr().err
            assert path in err and said in err and "Traceback" not in err, err
        results = check_vectors(path)
        assert len(results) == 1 and not results[0].ok and "cannot read vectors" in results[0].detail


def test_protocol_vectors_write_and_check(tmp_path, capsys):
    path = tmp_path / "v.json"
    assert protocol_main(["vectors", "--check", str(path)]) == 1  # missing
    assert protocol_main(["vectors", "--write", str(path)]) == 0
    assert protocol_main(["vectors", "--check", str(path)]) == 0
    assert path.read_text(encoding="utf-8") == VECTORS.read_text(encoding="utf-8")
    capsys.readouterr()


# =========================================================================== each vector, directly
_DOC = json.loads(VECTORS.read_text(encoding="utf-8"))


@pytest.mark.parametrize("vector", _DOC["frames"], ids=[v["name"] for v in _DOC["frames"]])
def test_frame_vector_both_ways(vector):
    cls = BY_ID[vector["msg_id"]]
    message = from_json(cls, vector["fields"])
    wire = bytes.fromhex(vector["wire_hex"])
    assert encode_frame(message, vector["seq"], vector["flags"]) == wire  # fields -> bytes
    [frame] = Deframer().feed(wire)  # bytes -> fields
    assert isinstance(frame, Frame)
    assert to_json(frame.message) == vector["fields"]
    assert (frame.seq, int(frame.flags)) == (vector["seq"], vector["flags"])
    assert cobs.decode(wire[:-1]).hex() == vector["frame_hex"]


@pytest.mark.parametrize("vector", _DOC["bad_frames"], ids=[v["name"] for v in _DOC["bad_frames"]])
def test_bad_frame_vector(vector):
    events = Deframer().feed(bytes.fromhex(vector["wire_hex"]))
    assert [(type(e), e.reason.value) for e in events] == [(BadFrame, vector["reason"])]
