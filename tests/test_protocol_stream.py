"""The Deframer on byte streams: any chunking, garbage between frames, corrupted bytes, overlong runs,
and a state machine comparing it with a model that decodes the whole stream at once."""

from __future__ import annotations

import os
import random
import tracemalloc

import hypothesis.strategies as st
from hypothesis import assume, given, settings
from hypothesis.stateful import RuleBasedStateMachine, invariant, rule
from test_protocol_strategies import numbered_stream, wire_frames

from protocol.errors import FrameError
from protocol.frame import (
    MAX_ENCODED,
    BadFrame,
    BadFrameReason,
    Deframer,
    Frame,
    decode_frame,
    decode_stream,
    encode_frame,
)
from protocol.messages import Heartbeat


def _split(data: bytes, cuts: list[int]) -> list[bytes]:
    points = sorted({c % (len(data) + 1) for c in cuts})
    bounds = [0, *points, len(data)]
    return [data[a:b] for a, b in zip(bounds, bounds[1:], strict=False)]


def _frames(events):
    return [e for e in events if isinstance(e, Frame)]


# =========================================================================== chunking and garbage
@given(numbered_stream(), st.lists(st.integers(0, 10_000), max_size=40))
def test_any_chunking_gives_the_same_frames(stream, cuts):
    wire = b"".join(w for _, w in stream)
    deframer = Deframer()
    events = [e for chunk in _split(wire, cuts) for e in deframer.feed(chunk)]
    assert [f.message for f in events] == [m for m, _ in stream]  # no bad frames, nothing lost
    c = deframer.counters
    assert (c.bytes, c.frames, c.bad_total, c.seq_gaps, c.duplicates) == (len(wire), len(stream), 0, 0, 0)


@given(numbered_stream(), st.data())
def test_garbage_between_frames_costs_no_frame(stream, data):
    """Line noise between frames (ended by a delimiter, as a sender's leading 0x00 or the previous
    frame's delimiter would provide) yields bad-frame events only for the noise."""
    wire = b""
    noise_chunks = 0
    for _, frame in stream:
        noise = data.draw(st.binary(max_size=300))
        assume(not _frames(decode_stream(noise + b"\x00")))  # noise that happens to be a valid frame
        wire += noise + b"\x00" + frame
        noise_chunks += sum(1 for part in noise.split(b"\x00") if part)
    cuts = data.draw(st.lists(st.integers(0, len(wire)), max_size=20))
    deframer = Deframer()
    events = [e for chunk in _split(wire, cuts) for e in deframer.feed(chunk)]
    assert [f.message for f in _frames(events)] == [m for m, _ in stream]
    bad = [e for e in events if isinstance(e, BadFrame)]
    assert len(bad) == noise_chunks
    assert deframer.counters.bad_total == noise_chunks


# =========================================================================== corruption
@settings(max_examples=60)
@given(numbered_stream(max_frames=20), st.data())
def test_corrupted_bytes_cost_only_the_frames_they_hit(stream, data):
    wires = [w for _, w in stream]
    wire = bytearray(b"".join(wires))
    owner = [i for i, w in enumerate(wires) for _ in w]  # frame index of every byte (delimiter included)
    hits = data.draw(st.lists(st.integers(0, len(wire) - 1), min_size=1, max_size=6, unique=True))
    for pos in hits:
        wire[pos] ^= data.draw(st.integers(1, 255))
    hit_frames = {owner[p] for p in hits}
    # A frame is lost if one of its bytes was hit, or if the previous frame's delimiter was (the two run
    # together). Nothing else may be lost.
    delimiter_hit = {owner[p] + 1 for p in hits if p == sum(len(w) for w in wires[: owner[p] + 1]) - 1}
    lost = hit_frames | delimiter_hit
    survivors = [m for i, (m, _) in enumerate(stream) if i not in lost]
    deframer = Deframer()
    cuts = data.draw(st.lists(st.integers(0, len(wire)), max_size=10))
    events = [e for chunk in _split(bytes(wire), cuts) for e in deframer.feed(chunk)]
    decoded = [f.message for f in _frames(events)]
    # Every frame not hit arrives, in order. (A damaged frame that passes its CRC by chance, p ≈ 2^-16,
    # would be an extra message, never a loss; at most one per damaged chunk.)
    rest = iter(decoded)
    assert all(any(m == d for d in rest) for m in survivors)
    assert len(decoded) - len(survivors) <= len(lost)
    c = deframer.counters
    chunks = [p for p in bytes(wire).split(b"\x00")[:-1] if p]  # complete chunks between delimiters
    assert c.frames == len(decoded)
    assert c.frames + c.bad_total == len(events) == len(chunks)
    assert c.bytes == len(wire)


# =========================================================================== overlong runs
def test_megabytes_without_a_delimiter_keep_memory_bounded():
    rng = random.Random(7)
    deframer = Deframer()
    junk = bytes(rng.randrange(1, 256) for _ in range(1 << 16))  # non-zero: never a delimiter
    tracemalloc.start()
    try:
        base, _ = tracemalloc.get_traced_memory()
        events = []
        for _ in range(64):  # 4 MiB in 64 KiB writes
            events += deframer.feed(junk)
        for b in junk[:2000]:  # and byte by byte
            events += deframer.feed(bytes([b]))
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak - base < 4 * len(junk)  # a couple of input-sized temporaries, not megabytes
    assert len(events) == 1 and events[0].reason is BadFrameReason.TOO_LONG
    assert deframer.counters.resyncs == 1
    # It resynchronises at the next delimiter: the chunk it was skipping is not reported again.
    frame = Heartbeat(time_ms=42)
    after = deframer.feed(b"\x00" + encode_frame(frame, 0))
    assert [e.message for e in after] == [frame]


def _peak_while_feeding(deframer: Deframer, data: bytes) -> tuple[list, int]:
    """The events of one ``feed(data)`` and the most memory allocated during it (bytes, tracemalloc)."""
    tracemalloc.start()
    try:
        base, _ = tracemalloc.get_traced_memory()
        events = deframer.feed(data)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return events, peak - base


def test_ten_megabytes_in_one_feed_keep_memory_within_the_frame_limit():
    """Regression: 10 MB of zero bytes made the deframer allocate 89 MB transiently (a list of ten million
    empty chunks), and a 10 MB run with a delimiter 30 MB (copies of the run). Whatever one feed holds,
    the deframer keeps at most one frame; what it allocates beyond its events stays a few frames."""
    bound = 16 * MAX_ENCODED
    frame = Heartbeat(time_ms=7)
    cases = {
        "zeros": (bytes(10_000_000), []),
        "run, then a delimiter": (b"\x55" * 10_000_000 + b"\x00", [BadFrameReason.TOO_LONG]),
        "a delimiter, then a run": (b"\x00" + b"\x55" * 10_000_000, [BadFrameReason.TOO_LONG]),
        "zeros around a frame": (bytes(5_000_000) + encode_frame(frame, 0) + bytes(5_000_000), [frame]),
    }
    for name, (data, expected) in cases.items():
        deframer = Deframer()
        deframer.feed(b"\x00")
        events, peak = _peak_while_feeding(deframer, data)
        assert peak < bound, f"{name}: {peak} bytes allocated"
        got = [e.message if isinstance(e, Frame) else e.reason for e in events]
        assert got == expected, name
        assert len(deframer._buf) <= MAX_ENCODED  # white-box: the partial frame it holds
    # A partial frame left by an earlier feed, then megabytes of its continuation without a delimiter.
    deframer = Deframer()
    deframer.feed(b"\x00" + encode_frame(frame, 1)[:5])
    events, peak = _peak_while_feeding(deframer, b"\x55" * 10_000_000)
    assert peak < bound and [e.reason for e in events] == [BadFrameReason.TOO_LONG]
    assert [e.message for e in deframer.feed(b"\x00" + encode_frame(frame, 2))] == [frame]


def test_random_bytes_in_random_chunks_never_raise():
    rng = random.Random(11)
    deframer = Deframer()
    total = 0
    for _ in range(300):
        chunk = os.urandom(rng.randrange(0, 700))
        total += len(chunk)
        for event in deframer.feed(chunk):
            assert isinstance(event, (Frame, BadFrame))
    assert deframer.counters.bytes == total


# =========================================================================== state machine vs. model
def _model_event(chunk: bytes):
    """What one complete chunk between delimiters must produce."""
    if len(chunk) > MAX_ENCODED:
        return ("bad", BadFrameReason.TOO_LONG)
    try:
        frame = decode_frame(chunk)
    except FrameError as exc:
        return ("bad", exc.reason)
    return ("frame", frame)


class DeframerVsModel(RuleBasedStateMachine):
    """The real Deframer, fed piece by piece, against a model that splits everything fed so far at the
    delimiters and decodes each complete chunk on its own."""

    def __init__(self) -> None:
        super().__init__()
        self.deframer = Deframer()
        self.events: list = []
        self.fed = 0
        self.done: list = []  # model events of completed chunks (and of chunks cut by reset)
        self.partial = b""  # bytes since the last delimiter

    def _feed(self, data: bytes) -> None:
        self.events += self.deframer.feed(data)
        self.fed += len(data)
        parts = (self.partial + data).split(b"\x00")
        self.partial = parts.pop()
        self.done += [_model_event(p) for p in parts if p]

    @rule(frame=wire_frames(), cut=st.integers(0, 300))
    def valid_frame_in_two_pieces(self, frame, cut):
        wire = frame[3]
        self._feed(wire[:cut])
        self._feed(wire[cut:])

    @rule(noise=st.binary(max_size=80))
    def noise(self, noise):
        self._feed(noise)

    @rule()
    def delimiter(self):
        self._feed(b"\x00")

    @rule(frame=wire_frames(), pos=st.integers(0, 1000), flip=st.integers(1, 255))
    def corrupted_frame(self, frame, pos, flip):
        wire = bytearray(frame[3])
        wire[pos % len(wire)] ^= flip
        self._feed(bytes(wire))

    @rule(n=st.integers(MAX_ENCODED - 3, 3 * MAX_ENCODED), step=st.integers(1, 400))
    def long_run_without_delimiter(self, n, step):
        run = bytes([0x55]) * n
        for i in range(0, n, step):
            self._feed(run[i : i + step])

    @rule()
    def reset(self):
        self.deframer.reset()
        if len(self.partial) > MAX_ENCODED:
            self.done.append(("bad", BadFrameReason.TOO_LONG))  # already reported before the reset
        self.partial = b""

    def _expected(self) -> list:
        pending = [("bad", BadFrameReason.TOO_LONG)] if len(self.partial) > MAX_ENCODED else []
        return self.done + pending

    @invariant()
    def same_events_as_the_model(self):
        got = [("frame", e) if isinstance(e, Frame) else ("bad", e.reason) for e in self.events]
        assert got == self._expected()

    @invariant()
    def counters_agree(self):
        c = self.deframer.counters
        expected = self._expected()
        assert c.bytes == self.fed
        assert c.frames == sum(1 for kind, _ in expected if kind == "frame")
        assert c.bad_total == sum(1 for kind, _ in expected if kind == "bad")
        assert c.resyncs == sum(1 for e in expected if e == ("bad", BadFrameReason.TOO_LONG))

    @invariant()
    def memory_is_bounded(self):
        assert len(self.deframer._buf) <= MAX_ENCODED  # the partial frame it holds (white-box check)


DeframerVsModel.TestCase.settings = settings(max_examples=60, stateful_step_count=30, deadline=None)
TestDeframerVsModel = DeframerVsModel.TestCase
