"""The hub's readers reconnecting at drawn moments (``Last-Event-ID``: :meth:`hil.gcs.hub.Hub.resume`),
across a live station's next run (:meth:`hil.gcs.hub.Hub.new_run`): every chunk of the run being read comes
once and in order, a reader that resumes gets no ``info`` and no history again, and once another run is
described no reader is given the last run's chunks."""

from __future__ import annotations

import re

from hypothesis import given, settings
from hypothesis import strategies as st

from hil.gcs.hub import Hub

ID = re.compile(rb"id: (\S+)\n\n")


def _chunks(data: bytes) -> list[bytes]:
    return re.findall(rb"event: c\ndata: (\S+)\n\n", data)


steps = st.lists(
    st.one_of(
        st.tuples(st.just("publish"), st.integers(1, 3)),
        st.tuples(st.just("read"), st.integers(1, 200)),
        st.just(("reconnect", 0)),
        st.just(("next_run", 0)),
    ),
    max_size=40,
)


@settings(max_examples=300, deadline=None)
@given(steps)
def test_readers_that_reconnect_at_any_moment_get_each_chunk_of_their_run_once(plan):
    hub = Hub(budget=1 << 20)
    run = 0
    hub.set_info(b"event: info\ndata: 0\n\n")
    published: dict[int, list[bytes]] = {0: []}
    reader, last_id = hub.reader(), None
    got: dict[int, list[bytes]] = {}
    seen_run = None
    n = 0

    def take(data: bytes) -> None:
        nonlocal last_id, seen_run
        infos = re.findall(rb"event: info\ndata: (\d+)", data)
        if infos:
            seen_run = int(infos[-1])
            got[seen_run] = []  # the whole history again after an info
        for chunk in _chunks(data):
            run_of = int(chunk.split(b".")[0])
            assert run_of == seen_run, (chunk, seen_run)  # never another run's chunk under this info
            got[seen_run].append(chunk)
        ids = ID.findall(data)
        if ids:
            last_id = ids[-1].decode()

    for what, k in plan:
        if what == "publish":
            for _ in range(k):
                chunk = f"{run}.{n}".encode()
                n += 1
                published[run].append(chunk)
                hub.publish(b"event: c\ndata: " + chunk + b"\n\n")
        elif what == "read":
            data = reader.read(0, max_bytes=k)
            if data:
                take(data)
        elif what == "reconnect":
            reader = hub.reader()
            hub.resume(reader, last_id)
        else:
            run += 1
            published[run] = []
            hub.new_run()
            hub.set_info(f"event: info\ndata: {run}\n\n".encode())
    while data := reader.read(0):
        take(data)
    assert seen_run == run
    assert got[run] == published[run]
