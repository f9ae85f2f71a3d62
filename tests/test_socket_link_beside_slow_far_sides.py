"""A board behind pyserial's ``socket://`` (a serial-to-TCP bridge, ser2net, a WiFi serial adapter), beside
the tested path: a real TCP far side on the loopback and the real client and transport.

1. **A reconnect whose connect waits.** The reader thread's reconnection opened the port under the
   client's lock, so while a TCP connect waited (the far side's accept queue full: pyserial waits up to
   5 s) every ``send_setpoint`` of the control thread waited with it — the run took its own tick for a
   stall (``host_stall``) instead of the link's loss. The port is now opened outside the lock.
2. **A fast far side.** pyserial's ``socket://`` says only *whether* bytes wait (``in_waiting`` 0 or 1),
   and the transport drained by that count: a byte a call, 1 MiB cost 7 s of CPU in 4 reads, the
   session fed nothing meanwhile. Such a port is now drained by one read of what has come.
3. **A lost link's close.** pyserial's ``socket://`` close sleeps 0.3 s; done under the client's lock, it
   held the control thread as long (a ``host_stall`` journalled for a TCP board's loss). The lost port is
   now closed outside the lock, as a reconnect's is opened.
"""

from __future__ import annotations

import select
import socket
import threading
import time

from hil.link.board import BoardClient
from hil.link.transports.serial_port import DRAIN_BYTES, SerialTransport
from protocol.frame import Deframer, Frame, Framer
from protocol.messages import SCHEMA_HASH, Ack, ActuatorSetpoint, BoardState, Hello, HelloReply, UnitSetpoint


class _TcpBoard:
    """A board on a TCP port: answers the handshake and every reliable command until :meth:`cut`, then
    closes the connection and fills its listener's accept queue, so that a new connect waits."""

    def __init__(self) -> None:
        self.listener = socket.socket()
        self.listener.bind(("127.0.0.1", 0))
        self.listener.listen(0)
        self.port = self.listener.getsockname()[1]
        self._cut = threading.Event()
        self._done = threading.Event()
        self._fillers: list[socket.socket] = []
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        conn, _ = self.listener.accept()
        deframer, framer = Deframer(), Framer()
        while not self._cut.is_set():
            ready, _, _ = select.select([conn], [], [], 0.02)
            if not ready:
                continue
            for event in deframer.feed(conn.recv(4096)):
                if not isinstance(event, Frame):
                    continue
                if isinstance(event.message, Hello):
                    reply = HelloReply(
                        schema_hash=SCHEMA_HASH,
                        state=BoardState.DISARMED,
                        n_units=1,
                        frame_rate_hz=50,
                        model="TCP",
                    )
                    conn.sendall(framer.encode(reply)[1])
                elif event.message.RELIABLE:
                    conn.sendall(framer.encode(Ack(msg_id=event.msg_id, seq=event.seq))[1])
        conn.close()
        for _ in range(4):  # the accept queue full: the next connect is neither taken nor refused
            filler = socket.socket()
            filler.setblocking(False)
            try:
                filler.connect(("127.0.0.1", self.port))
            except BlockingIOError:
                pass
            self._fillers.append(filler)
        self._done.set()

    def cut(self) -> None:
        self._cut.set()
        assert self._done.wait(5.0)

    def close(self) -> None:
        self._cut.set()
        self.thread.join(5.0)
        for s in self._fillers:
            s.close()
        self.listener.close()


def test_a_reconnect_whose_connect_waits_never_holds_the_callers_setpoints():
    board = _TcpBoard()
    client = BoardClient(f"socket://127.0.0.1:{board.port}")
    try:
        client.connect(timeout=5.0)
        client.start()
        setpoint = ActuatorSetpoint(units=(UnitSetpoint(0.0, 100.0),))
        board.cut()
        worst = 0.0
        end = time.monotonic() + 4.0  # the first reconnect tries come within ~1 s, each waiting seconds
        while time.monotonic() < end:
            started = time.monotonic()
            client.send_setpoint(setpoint)  # dropped and counted while no session is up
            assert client.state is not None
            worst = max(worst, time.monotonic() - started)
            time.sleep(0.02)
        assert not client.connected
        assert client.stats().as_dict()["counters.setpoints_dropped"] > 0
        # a busy CPU beside it may hold a thread off for a few hundred ms; a connect held under the lock
        # took 5 s a try
        assert worst < 2.0, f"send_setpoint waited {worst:.2f} s while the link reconnected"
    finally:
        client.close()
        board.close()


class _GatedClose(SerialTransport):
    """pyserial's ``socket://`` port, its close held until the test lets it go (pyserial's own close sleeps
    0.3 s, rfc2217's joins its reader for up to 7 s first: a wait the test can see without a stopwatch)."""

    def __init__(self, url: str) -> None:
        super().__init__(url)
        self.closing = threading.Event()
        self.release = threading.Event()

    def _close(self) -> None:
        self.closing.set()
        self.release.wait(10.0)
        super()._close()


def test_a_lost_links_close_never_holds_the_callers_setpoints():
    """3. **A lost link's close.** The reader closed the lost port under the client's lock, so pyserial's
    ``socket://`` close (a 0.3 s sleep) held the control thread's ``send_setpoint`` as long: the run
    journalled its own ``host_stall`` for a TCP board's loss. The port is now closed outside the lock."""
    board = _TcpBoard()
    transport = _GatedClose(f"socket://127.0.0.1:{board.port}")
    client = BoardClient(transport)
    setpoint = ActuatorSetpoint(units=(UnitSetpoint(0.0, 100.0),))
    try:
        client.connect(timeout=5.0)
        client.start()
        board.cut()
        assert transport.closing.wait(10.0), "the reader never closed the lost port"
        returned = threading.Event()

        def send() -> None:
            client.send_setpoint(setpoint)  # dropped and counted: no session is up
            returned.set()

        threading.Thread(target=send, daemon=True).start()
        held = not returned.wait(5.0)
        transport.release.set()
        assert not held, "send_setpoint waited for the lost port's close"
        assert not client.connected
    finally:
        transport.release.set()
        client.close()
        board.close()


def test_a_fast_far_side_is_drained_in_large_reads():
    size = 1 << 20
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(1)
    port = listener.getsockname()[1]
    opened = threading.Event()

    def far_side() -> None:
        conn, _ = listener.accept()
        # after the open: pyserial's socket:// open discards what is waiting (reset_input_buffer), and a
        # loaded machine once let the far side's bytes in before it
        assert opened.wait(30.0)
        conn.sendall(bytes(range(256)) * (size // 256))
        time.sleep(5.0)
        conn.close()

    thread = threading.Thread(target=far_side, daemon=True)
    thread.start()
    transport = SerialTransport(f"socket://127.0.0.1:{port}").open()
    opened.set()
    try:
        got = bytearray()
        reads = 0
        cpu = time.process_time()
        deadline = time.monotonic() + 30.0
        while len(got) < size and time.monotonic() < deadline:
            chunk = transport.read(0.5)
            assert len(chunk) <= DRAIN_BYTES
            got += chunk
            reads += 1
        cpu = time.process_time() - cpu
        assert bytes(got) == bytes(range(256)) * (size // 256)  # every byte, in order
        assert reads < 200, f"{reads} reads for 1 MiB"  # a byte a call took 4 reads of 256 KiB, each 2 s
        assert cpu < 2.0, f"{cpu:.2f} s of CPU for 1 MiB"
    finally:
        transport.close()
        listener.close()
        thread.join(10.0)
