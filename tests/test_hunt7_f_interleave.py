"""Hunt 7, area F: two senders on one arbitration id (a misconfigured second board at this board's node
id), and a segment lost at every position. No defect was found here; these properties guard what was
checked: the reassembler never delivers a frame joined from two senders' segments — every frame it hands
up is one a sender sent, whole — and a frame that lost any one segment is counted once, never delivered."""

from __future__ import annotations

import hypothesis.strategies as st
from hypothesis import given, settings

from protocol.can import CanReassembler, CanSegmenter, Direction
from protocol.frame import Framer
from protocol.messages import Log

NODE = 5


@settings(max_examples=150, deadline=None)
@given(
    fd=st.booleans(),
    texts=st.lists(st.tuples(st.integers(0, 120), st.integers(0, 120)), min_size=1, max_size=6),
    order=st.lists(st.booleans(), max_size=400),
)
def test_two_boards_on_one_node_never_yield_a_frame_neither_sent(fd, texts, order):
    """Board A and board B at one node id each send Log frames on the same arbitration id (their transfer
    ids both from 0); their segments interleave as ``order`` draws (True: A's next). Every delivered frame
    is one of the frames sent, byte for byte; the rest are counted as losses."""
    a, b = CanSegmenter(NODE, Direction.TO_HOST, fd), CanSegmenter(NODE, Direction.TO_HOST, fd)
    framer_a, framer_b = Framer(0), Framer(0)
    sent: set[bytes] = set()
    queue_a, queue_b = [], []
    for len_a, len_b in texts:
        wire_a = framer_a.encode(Log(code=1, text="a" * len_a))[1]
        wire_b = framer_b.encode(Log(code=2, text="b" * len_b))[1]
        sent |= {wire_a, wire_b}
        queue_a += a.segment(wire_a)
        queue_b += b.segment(wire_b)
    rx = CanReassembler(NODE, Direction.TO_HOST, fd=fd)
    picks = iter(order)
    delivered = []
    t = 10.0
    while queue_a or queue_b:
        take_a = queue_a and (not queue_b or next(picks, True))
        seg = (queue_a if take_a else queue_b).pop(0)
        t += 0.0005
        wire = rx.feed(seg.arbitration_id, seg.data, fd, False, t)
        if wire:
            delivered.append(wire)
    assert all(wire in sent for wire in delivered)
    assert rx.partial_frames <= rx.window  # memory bounded however the two interleave


@settings(max_examples=150, deadline=None)
@given(fd=st.booleans(), length=st.integers(0, 200), data=st.data())
def test_a_segment_lost_at_any_position_costs_that_frame_only_counted_once(fd, length, data):
    """A Log frame loses the segment at a drawn position; the next frame on its arbitration id arrives
    whole. The damaged frame is never delivered and is counted ``incomplete`` exactly once; the next is
    delivered whole."""
    seg, framer = CanSegmenter(NODE, Direction.TO_HOST, fd), Framer(0)
    first = framer.encode(Log(code=7, text="x" * length))[1]
    second = framer.encode(Log(code=8, text="y"))[1]
    segments = seg.segment(first)
    if len(segments) < 2:
        return  # a one-segment frame lost whole is no partial frame
    lost = data.draw(st.integers(0, len(segments) - 1), label="lost segment")
    rx = CanReassembler(NODE, Direction.TO_HOST, fd=fd)
    got = b""
    for i, s in enumerate(segments):
        if i != lost:
            got += rx.feed(s.arbitration_id, s.data, fd)
    assert got == b""  # never delivered half-built
    for s in seg.segment(second):
        got += rx.feed(s.arbitration_id, s.data, fd)
    assert got == second
    assert rx.stats.incomplete + rx.stats.cut == 1 and rx.stats.frames == 1
