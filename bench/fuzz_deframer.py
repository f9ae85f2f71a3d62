#!/usr/bin/env python
"""Coverage-guided fuzzing (atheris / libFuzzer) of everything that parses bytes from the wire.

    python bench/fuzz_deframer.py -runs=1000000 -print_final_stats=1   # a million inputs, then stats
    python bench/fuzz_deframer.py -max_total_time=60 corpus/           # a minute, new inputs to corpus/
    python bench/fuzz_deframer.py -help=1                              # libFuzzer's own options

Not a pytest test and not a benchmark of its own (it is not named ``bench_*``): ``bench/bench_protocol.py``
runs a short burst of it in a subprocess for the inputs/s figure. The first byte of each input picks a
target, the rest is the target's input:

* 0 — ``Deframer.feed`` on the bytes cut into chunks (sizes taken from the input), checking that every
  event is a ``Frame`` or ``BadFrame``, the counters add up, memory stays within one frame, and every
  decoded frame re-encodes to bytes that decode to the same frame;
* 1 — ``decode_frame`` on one chunk: a ``Frame`` or a ``FrameError``, nothing else;
* 2 — ``CanReassembler`` on a sequence of CAN frames (2-byte id, flags, length, data) feeding a deframer,
  checking its memory bound and that it only ever delivers whole wire frames.

Any other exception, or a failed check, is a crash: libFuzzer stops and writes the input to
``crash-<sha1>``. The corpus is seeded with every frame, bad frame and stream of the protocol test
vectors (and their CAN segmentations), so the fuzzer starts from deep inside the format.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import atheris
from fuzz_main import run_fuzzer  # beside this script (it runs as one)

with atheris.instrument_imports(include=["protocol"]):
    from protocol import cobs, fields, frame, messages  # noqa: F401  (instrumented for coverage)
    from protocol.can import CanReassembler, CanSegmenter, Direction
    from protocol.errors import FrameError
    from protocol.frame import MAX_ENCODED, BadFrame, Deframer, Frame, decode_frame, encode_frame

VECTORS = Path(__file__).resolve().parent.parent / "fixtures" / "protocol_vectors.json"
TARGET_DEFRAMER, TARGET_DECODE, TARGET_CAN = 0, 1, 2


def fuzz_deframer(data: bytes) -> None:
    deframer = Deframer()
    # Chunk sizes come from the input's tail so the same bytes are also tried with other splits.
    sizes = data[-4:] if len(data) > 8 else b"\xff"
    events: list = []
    pos, k = 0, 0
    while pos < len(data):
        step = 1 + sizes[k % len(sizes)]
        events += deframer.feed(data[pos : pos + step])
        pos += step
        k += 1
        assert len(deframer._buf) <= MAX_ENCODED, "partial frame buffer grew past one frame"
    c = deframer.counters
    assert c.bytes == len(data)
    assert c.frames == sum(isinstance(e, Frame) for e in events)
    assert c.bad_total == sum(isinstance(e, BadFrame) for e in events) == len(events) - c.frames
    for e in events:
        if isinstance(e, Frame):
            again = decode_frame(encode_frame(e.message, e.seq, int(e.flags))[:-1])
            assert again == e, f"re-encoded frame decodes differently: {e!r} -> {again!r}"


def fuzz_decode(data: bytes) -> None:
    chunk = data.replace(b"\x00", b"\x01")  # a chunk between delimiters never holds 0x00
    try:
        result = decode_frame(chunk)
    except FrameError:
        return
    assert isinstance(result, Frame)


def fuzz_can(data: bytes) -> None:
    rx = CanReassembler(window=2, max_streams=4)
    deframer = Deframer()
    pos = 0
    while pos + 4 <= len(data):
        arb = int.from_bytes(data[pos : pos + 2], "little") & 0x7FF
        flags, n = data[pos + 2], data[pos + 3] % 65
        payload = data[pos + 4 : pos + 4 + n]
        pos += 4 + n
        wire = rx.feed(arb, payload, is_fd=bool(flags & 1), is_extended_id=bool(flags & 2))
        assert wire == b"" or (wire.endswith(b"\x00") and wire.count(0) == 1), "delivered a partial frame"
        for event in deframer.feed(wire):
            assert isinstance(event, (Frame, BadFrame))
        assert rx.partial_frames <= 2 * 4


TARGETS = {TARGET_DEFRAMER: fuzz_deframer, TARGET_DECODE: fuzz_decode, TARGET_CAN: fuzz_can}


def test_one_input(data: bytes) -> None:
    if not data:
        return
    TARGETS[data[0] % len(TARGETS)](data[1:])


# =========================================================================== seed corpus
def seeds() -> list[bytes]:
    """Inputs built from the protocol test vectors, one or more per target."""
    doc = json.loads(VECTORS.read_text(encoding="utf-8"))
    wires = [bytes.fromhex(v["wire_hex"]) for key in ("frames", "bad_frames", "streams") for v in doc[key]]
    out = []
    for wire in wires:
        out.append(bytes([TARGET_DEFRAMER]) + wire)
        out.append(bytes([TARGET_DECODE]) + wire[:-1])
    for fd in (False, True):
        seg = CanSegmenter(5, Direction.TO_HOST, fd=fd)
        for v in doc["frames"][:12]:
            packed = b""
            for f in seg.segment(bytes.fromhex(v["wire_hex"])):
                packed += f.arbitration_id.to_bytes(2, "little") + bytes([int(fd), len(f.data)]) + f.data
            out.append(bytes([TARGET_CAN]) + packed)
    return out


def main(argv: list[str]) -> None:
    run_fuzzer(argv, seeds(), test_one_input, "vscmg-fuzz-seeds-")


if __name__ == "__main__":
    main(sys.argv)
