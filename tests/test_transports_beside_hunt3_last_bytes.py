"""A far side's last bytes before it goes, beside the path: a board behind pyserial's ``socket://`` (a
serial-to-TCP bridge) whose final bytes come in a segment of their own just before the connection ends —
a bridge forwards a 115200-baud board's bytes as they come, so a frame's final 0x00 is often alone — had
them taken by the read that then met the end and raised: the read failed, and the bytes it had taken were
lost with it (the board's last frame, its delimiter never seen). They are now handed up by that read, and
the failure raised by the next one (as a CAN bus's completed frames already were).

A real TCP far side on loopback, real pyserial; the moment the far side ends is drawn."""

from __future__ import annotations

import socket
import threading

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.link.transports import create_transport
from protocol.errors import LinkError


class _FarSide:
    """A TCP far side: waits for the host's first byte (so pyserial's flush at open is behind it), sends
    ``head``, waits until told, sends ``tail`` and closes its end."""

    def __init__(self, head: bytes, tail: bytes) -> None:
        self.server = socket.create_server(("127.0.0.1", 0))
        self.port = self.server.getsockname()[1]
        self.head, self.tail = head, tail
        self.send_tail = threading.Event()
        self.closed = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        conn, _ = self.server.accept()
        with conn:
            conn.recv(1)
            conn.sendall(self.head)
            self.send_tail.wait(10.0)
            conn.sendall(self.tail)
        self.closed.set()

    def close(self) -> None:
        self.send_tail.set()
        self.thread.join(10.0)
        self.server.close()


def _read_until_lost(transport, want: int | None = None) -> tuple[bytes, LinkError | None]:
    got = b""
    for _ in range(400):
        try:
            got += transport.read(0.05)
        except LinkError as exc:
            return got, exc
        if want is not None and len(got) >= want:
            return got, None
    return got, None


@given(
    stream=st.binary(min_size=2, max_size=400).map(lambda b: b.replace(b"\x00", b"\x7e") + b"\x00"),
    tail_length=st.integers(1, 6),
)
@settings(max_examples=20, deadline=None)
def test_every_byte_a_socket_far_side_sent_before_it_closed_is_handed_up_before_the_loss(stream, tail_length):
    tail_length = min(tail_length, len(stream) - 1)
    head, tail = stream[:-tail_length], stream[-tail_length:]
    far = _FarSide(head, tail)
    transport = create_transport(f"socket://127.0.0.1:{far.port}").open()
    try:
        transport.write(b"\x00")
        got, lost = _read_until_lost(transport, len(head))
        assert lost is None and got == head
        far.send_tail.set()
        assert far.closed.wait(10.0)
        rest, lost = _read_until_lost(transport)
        assert got + rest == stream  # the far side's last frame, its delimiter included
        assert lost is not None  # and then the loss, said
        with pytest.raises(LinkError):
            transport.read(0.05)  # and said again: the port stays lost until reopened
    finally:
        transport.close()
        far.close()


def test_a_failure_kept_for_the_next_read_is_forgotten_by_a_close():
    far = _FarSide(b"\x01\x02", b"\x00")
    transport = create_transport(f"socket://127.0.0.1:{far.port}").open()
    try:
        transport.write(b"\x00")
        _read_until_lost(transport, 2)
        far.send_tail.set()
        assert far.closed.wait(10.0)
        assert _read_until_lost(transport, 1) == (b"\x00", None)  # the failure is kept for the next read
        transport.close()  # the client reconnects: the bridge is back, on the same port
        far.head, far.tail = b"\x05\x00", b""
        far.send_tail.clear()
        far.closed.clear()
        far.thread = threading.Thread(target=far._run, daemon=True)
        far.thread.start()
        transport.open()
        transport.write(b"\x00")
        assert _read_until_lost(transport, 2) == (b"\x05\x00", None)  # afresh: not the old failure
    finally:
        transport.close()
        far.close()
