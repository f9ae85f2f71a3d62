"""The fault soak's phone in real time: a UDP relay between firmware-sim's simulated phone and the host
(SensaGram datagrams), which can pause the stream and resume it, and a hostile peer's datagrams sent
straight to the host's port.

The relay stands where the network stands between a phone and the host: firmware-sim --world streams to
the relay's port, the relay forwards every datagram to the host's, except while paused (a phone app that
stops streaming and starts again: its datagrams are lost, its clock goes on).
"""

from __future__ import annotations

import json
import os
import socket
import threading
import time


class PhoneRelay:
    """Forward UDP datagrams from a port of its own (``url``) to ``forward`` (``(host, port)``), unless
    paused; ``forwarded`` and ``dropped`` count them."""

    def __init__(self, forward: tuple[str, int]) -> None:
        self.forward = forward
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.05)
        self.out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.forwarded = self.dropped = 0
        self.newest_ns: int | None = None  # the newest SensaGram timestamp seen (the phone's clock)
        self._paused_until = 0.0
        self._seen_listening = False
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="soak-relay", daemon=True)

    @property
    def url(self) -> str:
        host, port = self.sock.getsockname()
        return f"udp://{host}:{port}"

    def start(self) -> PhoneRelay:
        self._thread.start()
        return self

    def pause(self, seconds: float) -> None:
        """Drop everything for ``seconds`` from now (monotonic)."""
        self._paused_until = time.monotonic() + seconds

    def _listening(self) -> bool:
        """Whether a socket is bound to the host's port yet (Linux: ``/proc/net/udp``). Until the host
        listens, what the phone streams is lost and counted ``dropped``, not ``forwarded``: the kernel
        takes a datagram for an unbound port without a word (sendto succeeds), and the soak's every-
        datagram check would count it against the host. Once seen, it is not asked again."""
        if self._seen_listening:
            return True
        suffix = f":{self.forward[1]:04X}"  # local_address is HEXIP:HEXPORT, the second field
        try:
            with open("/proc/net/udp") as table:
                next(table)  # the header
                self._seen_listening = any(line.split()[1].endswith(suffix) for line in table)
        except OSError:
            self._seen_listening = True  # no such table: the old behaviour, counted from the start
        return self._seen_listening

    def stop_forwarding(self) -> None:
        """Forward nothing more (what comes is counted ``dropped``): the soak's end, before the host closes
        its receiver, so every datagram counted ``forwarded`` reached a listening host."""
        self._paused_until = float("inf")

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        self.sock.close()
        self.out.close()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data = self.sock.recv(65_535)
            except TimeoutError:
                continue
            except OSError:
                return
            if time.monotonic() < self._paused_until or not self._listening():
                self.dropped += 1
                continue
            self._note_time(data)
            try:
                self.out.sendto(data, self.forward)
                self.forwarded += 1
            except OSError:  # the host is not listening (yet, or any more): a phone keeps streaming
                self.dropped += 1

    def _note_time(self, data: bytes) -> None:
        try:
            stamp = json.loads(data)["timestamp"]
        except (ValueError, KeyError, TypeError):
            return
        if isinstance(stamp, int):
            self.newest_ns = stamp


def hostile_datagrams(phone_now_ns: int | None) -> tuple[list[bytes], int]:
    """What a peer on the network may send to the host's phone port: datagrams no decoder takes (deep
    brackets, oversized, binary, wrong shapes, numbers past every limit, NaN) and, if the phone's clock is
    known, well-formed samples that parse but are hostile: stamped an hour before it or 100 s after it, at
    1e18 ns, values of 1e160 or a gyro at 1e6 rad/s (the host's admission policy drops and counts them;
    none may stall it, reset its estimator or pass for a phone that restarted). Returns them and how many
    are unreadable."""
    bad = [
        b"[" * 60_000,
        b"{" * 5_000,
        os.urandom(1_400),
        b"\xff\xfe\x00garbage",
        b"",
        b"null",
        b"[1, 2, 3]",
        b'{"type": 7}',
        b'{"type": "android.sensor.gyroscope", "timestamp": "soon", "values": [0, 0, 0]}',
        b'{"type": "android.sensor.gyroscope", "timestamp": 1e400, "values": [0, 0, 0]}',
        b'{"type": "android.sensor.gyroscope", "timestamp": ' + b"9" * 5_000 + b', "values": [0, 0, 0]}',
        b'{"type": "android.sensor.accelerometer", "timestamp": 1, "values": [NaN, 0, 0]}',
        b'{"type": "android.sensor.magnetic_field", "timestamp": 1, "values": [1, 2]}',
        b'{"type": "android.sensor.gyroscope", "timestamp": 1, "values": [1, 2, 3]' + b" " * 5_000 + b"}",
    ]
    stray: list[bytes] = []
    if phone_now_ns is not None:
        ahead = phone_now_ns + 100 * 10**9
        for stamp in (phone_now_ns - 3_600 * 10**9, ahead):  # an hour behind; 100 s ahead (issue 26, 3)
            for kind in ("gyroscope", "accelerometer", "magnetic_field"):
                doc = {"type": f"android.sensor.{kind}", "timestamp": stamp, "values": [0.0, 0.0, 9.8]}
                stray.append(json.dumps(doc).encode())
        absurd = [  # they parse: the host's admission policy drops and counts them (issue 26, 1 and 2)
            ("gyroscope", 10**18, [0.0, 0.0, 0.1]),  # stamped 1e18 ns: once a host hang
            ("gyroscope", phone_now_ns, [1e160, -1e160, 1e160]),  # once a crash (a NaN setpoint)
            ("gyroscope", phone_now_ns, [1e6, 0.0, 0.0]),  # 1e6 rad/s: once a run that said completed
            ("accelerometer", phone_now_ns, [0.0, 0.0, 1e300]),
        ]
        for kind, stamp, values in absurd:
            doc = {"type": f"android.sensor.{kind}", "timestamp": stamp, "values": values}
            stray.append(json.dumps(doc).encode())
    return bad + stray, len(bad)


def send(
    datagrams: list[bytes], to: tuple[str, int], repeat: int = 1, sock: socket.socket | None = None
) -> int:
    """Send each datagram ``repeat`` times, from ``sock`` (the phone's own socket: the host follows one
    sender, and another's datagrams never reach its checks) or a socket of their own; the number that left
    (an oversized one may not)."""
    s = sock if sock is not None else socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sent = 0
    try:
        for _ in range(repeat):
            for data in datagrams:
                try:
                    s.sendto(data, to)
                    sent += 1
                except OSError:
                    pass
    finally:
        if sock is None:
            s.close()
    return sent
