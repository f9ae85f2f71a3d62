"""Live phone samples over UDP: the SensaGram app's stream, received and sent.

*SensaGram* (Umer Farooq, Android 5+, GPL-3.0, on F-Droid and github.com/UmerCodez/SensaGram) sends one UDP
datagram per Android ``SensorEvent`` to the address and port set in its settings: a JSON object ::

    {"timestamp": 3925657519043709, "values": [0.31, -0.97, 10.04], "type": "android.sensor.accelerometer"}

``timestamp`` is the event's ``SensorEvent.timestamp`` in nanoseconds (the phone's boot clock, not the
epoch: every sensor shares it, so the rate mismatch survives), ``values`` the event's values, ``type`` the
sensor's Android string type. Used here: ``android.sensor.accelerometer`` (m/s², gravity included),
``android.sensor.gyroscope`` (rad/s) and ``android.sensor.magnetic_field`` (µT), all in the Android sensor
frame (x screen right, y screen up, z out of the screen) — exactly what the estimator takes. A stream
that carries a sensor's uncalibrated type instead (``android.sensor.gyroscope_uncalibrated``,
``…magnetic_field_uncalibrated``, ``…accelerometer_uncalibrated``: six values, the raw reading then the OS's
estimate of its bias, or of the hard-iron field) is read as the raw reading less that estimate — what the
calibrated sensor reports — while the calibrated type of that sensor is not streaming: from its first
event on, the stream's uncalibrated events of it are ignored and counted, so that two sensors' readings are
never interleaved as one, until it has been silent for :data:`~.stream.CALIBRATED_QUIET_S` (turned off in
the app mid-run: counted, ``calibrated_lapses``, and logged; the uncalibrated type is read again). Other
types (``android.gps``, light, rotation vector, …) are ignored and counted. There is no batching, so the
sensing latency is the network's; there is no sequence number, so a lost datagram is not noticed (the
merger's gap and stale flags are what shows it).

**One phone.** A datagram carries no phone's name: its sender is its source address *and port* (one app's
socket). The receiver follows the first sender heard with a reading the host uses; every other sender's
datagrams are dropped, counted and logged, never merged (two phones on one network, both streaming to this
port). An app restarted comes back from a new source port: it is followed once the old port has been silent
for :data:`~.senders.SWITCH_AFTER_S` — a phone that streamed alongside the followed one never is
(:mod:`.senders`: the rule and why). Nothing authenticates a phone: any host can send from any address.

:class:`PhoneUdpReceiver` is the receiving end (the host); :class:`PhoneUdpSender` is the sending end (the
emulator's simulated phone streams to the host exactly as the app would). Parsing is a pure function,
:func:`decode_datagram`, tested without sockets.
"""

from __future__ import annotations

import contextlib
import json
import math
import socket
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from hil.estimation.sensors import SensorKind, SensorSample
from hil.link.sources.senders import Decision
from hil.link.sources.stream import MAX_BATCH, MAX_QUEUE, PhoneReceiver, parse_json, reading_number, split_url
from protocol.errors import ConfigError, InputFormatError, LinkError

TYPES: dict[str, SensorKind] = {
    "android.sensor.accelerometer": SensorKind.ACC,
    "android.sensor.gyroscope": SensorKind.GYR,
    "android.sensor.magnetic_field": SensorKind.MAG,
}
_TYPE_OF = {kind: name for name, kind in TYPES.items()}
UNCALIBRATED: dict[str, SensorKind] = {
    "android.sensor.accelerometer_uncalibrated": SensorKind.ACC,
    "android.sensor.gyroscope_uncalibrated": SensorKind.GYR,
    "android.sensor.magnetic_field_uncalibrated": SensorKind.MAG,
}
"""Android's uncalibrated types: ``values`` the raw reading (3), then the OS's estimate of its bias (3)."""


@dataclass(frozen=True, slots=True)
class UncalibratedSample(SensorSample):
    """A reading of a sensor's uncalibrated type, its bias estimate removed: used by the receiver only
    while the calibrated type of its sensor is not streaming (the module docstring)."""


MAX_DATAGRAM = 65_507  # bytes: the largest UDP payload over IPv4
MAX_MESSAGE = 4096  # bytes: a SensaGram datagram is ~100; a larger one is dropped unparsed
MAX_BRACKETS = 8  # a SensaGram datagram holds one object and one list; deeper ones are dropped unparsed


def decode_datagram(data: bytes, source: str = "udp") -> SensorSample | None:
    """One SensaGram datagram → its sample (seconds on the phone's clock), or None for another sensor; an
    uncalibrated type's as an :class:`UncalibratedSample`, its raw reading less its bias estimate (the
    raw reading when the event has no finite estimate).

    A datagram that is not a JSON object with a string ``type``, or one of our sensors without an integer
    or numeric ``timestamp`` and three finite numbers in ``values`` (a bool is none:
    :func:`~.stream.reading_number`), raises :class:`InputFormatError` naming ``source`` — whatever the
    bytes, nothing else is raised.
    """
    if len(data) > MAX_MESSAGE:
        raise InputFormatError(f"a datagram of {len(data)} bytes is larger than {MAX_MESSAGE}", source)
    if data.count(b"[") + data.count(b"{") > MAX_BRACKETS:  # refused before the parser spends ~0.3 ms
        raise InputFormatError(f"more than {MAX_BRACKETS} brackets: not one sensor event", source)
    doc = parse_json(data, source)
    if not isinstance(doc, dict) or not isinstance(doc.get("type"), str):
        raise InputFormatError("expected a JSON object with a string 'type'", source)
    name = doc["type"].strip().lower()  # Android's names are lower case; a client's may not be
    raw = name not in TYPES
    kind = UNCALIBRATED.get(name) if raw else TYPES[name]
    if kind is None:
        return None
    t_ns, values = doc.get("timestamp"), doc.get("values")
    if isinstance(t_ns, str) and t_ns.strip().isascii() and t_ns.strip().isdigit():  # its long as a string
        t_ns = int(t_ns)
    if isinstance(t_ns, bool) or not isinstance(t_ns, (int, float)):
        raise InputFormatError(f"{doc['type']}: 'timestamp' must be a number of nanoseconds", source)
    if not isinstance(values, list) or len(values) < 3:
        raise InputFormatError(f"{doc['type']}: 'values' must be a list of 3 numbers", source)
    x, y, z = (reading_number(v) for v in values[:3])
    if x is None or y is None or z is None:  # a bool, a list, a NaN: no reading (never true as 1.0)
        raise InputFormatError(f"{doc['type']}: 'values' must be finite numbers", source)
    xyz = (x, y, z)
    try:
        t = t_ns / 1_000_000_000  # int / int: correctly rounded, so t_s survives a round trip through ns
    except OverflowError:
        raise InputFormatError(f"{doc['type']}: time and 'values' must be finite numbers", source) from None
    if not math.isfinite(t):
        raise InputFormatError(f"{doc['type']}: time and values must be finite", source)
    if not raw:
        return SensorSample(t, kind, xyz)
    bias = _bias(values)
    if bias is not None:
        xyz = (xyz[0] - bias[0], xyz[1] - bias[1], xyz[2] - bias[2])
        if not all(math.isfinite(v) for v in xyz):  # 1e308 less -1e308: finite parts, no finite reading
            raise InputFormatError(f"{doc['type']}: the reading less its bias is not finite", source)
    return UncalibratedSample(t, kind, xyz)


def _bias(values: list[object]) -> tuple[float, float, float] | None:
    """An uncalibrated event's bias estimate (``values[3:6]``), or None when it has none that is finite."""
    if len(values) < 6:
        return None
    bx, by, bz = (reading_number(v) for v in values[3:6])
    return None if bx is None or by is None or bz is None else (bx, by, bz)


def encode_datagram(sample: SensorSample) -> bytes:
    """The datagram SensaGram sends for ``sample`` (the inverse of :func:`decode_datagram`)."""
    doc = {"timestamp": round(sample.t_s * 1e9), "values": list(sample.xyz), "type": _TYPE_OF[sample.kind]}
    return json.dumps(doc, separators=(",", ":")).encode()


def _address(url: str) -> tuple[str, int]:
    host, port, _ = split_url(url, "udp", "udp://HOST:PORT")
    return host, port


def sender_address(url: str, where: str = "--phone") -> tuple[str, int]:
    """The IPv4 address and port a :class:`PhoneUdpSender` sends ``url``'s datagrams to, resolved once; a
    :class:`ConfigError` naming ``where`` for what no datagram could reach: a malformed URL, port 0 (a
    listener's "any free port"), an IPv6 address or a name without an IPv4 one (the sender's socket is
    IPv4: every datagram failed, only counted). Checked when the sender is made, so the option is refused
    at start."""
    host, port, _ = split_url(url, "udp", "udp://HOST:PORT", where=where, sending=True)
    if ":" in host:
        raise ConfigError(
            f"{url!r}: {host} is an IPv6 address; the simulated phone streams over IPv4: give an IPv4 "
            "address (udp://127.0.0.1:PORT for this machine)",
            where,
        )
    try:
        found = socket.getaddrinfo(host, port, socket.AF_INET, socket.SOCK_DGRAM)
    except (OSError, UnicodeError) as exc:  # socket.gaierror is an OSError; a bad IDNA name a UnicodeError
        why = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
        raise ConfigError(f"{url!r}: no IPv4 address for {host!r} ({why})", where) from None
    address, found_port = found[0][4][:2]
    return str(address), int(found_port)


SO_RXQ_OVFL = getattr(socket, "SO_RXQ_OVFL", 40)
"""Linux's socket option (40) that has the kernel hand each datagram's reader the count of datagrams it
dropped on that socket for want of buffer space (a uint32, cumulative)."""
OVERFLOW_SPACE = socket.CMSG_SPACE(4)


def _count_overflows(sock: socket.socket) -> bool:
    """Ask the kernel to report its drops on ``sock`` (Linux); False where it cannot (then a drop in the
    kernel goes uncounted by the receiver: the platform's limit, said in docs/formats.md)."""
    try:
        sock.setsockopt(socket.SOL_SOCKET, SO_RXQ_OVFL, 1)
    except OSError:
        return False
    return True


class PhoneUdpReceiver(PhoneReceiver):
    """Receives SensaGram datagrams on ``udp://HOST:PORT`` (port 0 picks a free one; see :attr:`url`).

    A background thread reads the socket; a datagram that cannot be read, whatever is in it, is counted
    (``stats.bad_messages``) and logged, never fatal. :meth:`drain` hands over what arrived, at most
    ``max_batch`` samples a call (a flood of datagrams is held, then dropped oldest first beyond
    ``max_queue``: :mod:`.stream`); :meth:`check` raises the thread's error (only the socket itself failing
    is one). It follows one phone (the module docstring); ``clock`` (s, monotonic) times that phone's
    silence and paces the warnings.
    """

    scheme = "udp"
    app = "SensaGram (UDP)"

    def __init__(
        self,
        url: str,
        max_queue: int = MAX_QUEUE,
        max_batch: int = MAX_BATCH,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        super().__init__(max_queue, clock, max_batch)
        host, port = _address(url)
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            # A phone streams hundreds of datagrams a second; a deep receive buffer rides out a slow tick.
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 * 1024 * 1024)
            self.counts_kernel_drops = _count_overflows(self._sock)
            self._sock.bind((host, port))
        except OSError as exc:
            self._sock.close()
            raise LinkError(f"cannot listen for the phone on udp://{host}:{port}: {exc.strerror}") from exc
        self._sock.settimeout(0.05)
        bound_host, bound_port = self._sock.getsockname()[:2]
        self._url = f"udp://{bound_host}:{bound_port}"  # kept: still answers after close()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="phone-udp", daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        return self._url

    def _serve(self) -> None:
        try:
            while not self._stop.is_set():
                try:
                    data, ancillary, _flags, peer = self._sock.recvmsg(MAX_DATAGRAM, OVERFLOW_SPACE)
                except (TimeoutError, ConnectionError):  # idle; an ICMP error queued on the socket
                    continue
                for level, kind, value in ancillary:
                    if (level, kind) == (socket.SOL_SOCKET, SO_RXQ_OVFL) and len(value) >= 4:
                        self._kernel_dropped(int.from_bytes(value[:4], sys.byteorder))
                self._accept(data, peer)
        except OSError as exc:
            if not self._stop.is_set():  # a socket closed by close() is the normal end
                self._thread_error.store(exc)
        except BaseException as exc:  # stored, raised by check()
            self._thread_error.store(exc)

    def _accept(self, data: bytes, peer: tuple[str, int]) -> None:
        sample, refused = self._decode(decode_datagram, data, f"udp from {peer[0]}")
        if refused:
            return
        host, port = peer[0], peer[1]
        decision = self._attribute((host, port), f"{host}:{port}", sample is not None)
        if decision is Decision.OTHER:
            return
        if decision is Decision.NOTHING:  # another sensor only: nothing of it dropped, no stream state
            self._deliver((), ignored=1)
            return
        if decision is Decision.SWITCHED:  # another app's stream: which sensors it calibrates is its own
            self._calibrated_forget()
        streaming = self._calibrated_streaming()  # a calibrated type silent too long lapses here
        if sample is None:
            self._deliver((), ignored=1)
        elif type(sample) is UncalibratedSample:  # only while its sensor's calibrated type is not streaming
            if sample.kind.label in streaming:
                self._deliver((), ignored=1)
            else:
                self._deliver((SensorSample(sample.t_s, sample.kind, sample.xyz),))
        else:
            self._calibrated_heard((sample.kind.label,))
            self._deliver((sample,))

    def close(self) -> None:
        """Stop the thread and release the port. Idempotent."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5.0)
        self._sock.close()


class PhoneUdpSender:
    """Sends samples to ``udp://HOST:PORT`` as SensaGram does: one datagram each, fire and forget (nobody
    listening is not an error for UDP; a datagram the socket refuses — no route, full buffer — is counted
    in ``failed``). A phone keeps streaming while the host restarts. An address no datagram could ever
    reach (port 0, IPv6, a name without an IPv4 address) is a :class:`ConfigError` when the sender is made
    (:func:`sender_address`)."""

    batch_s = 0.0  # every event as it happens

    def __init__(self, url: str) -> None:
        self.url = url
        self._address = sender_address(url)  # a URL no datagram could reach is refused here, not counted
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sent = 0
        self.failed = 0

    def send(self, samples: Sequence[SensorSample]) -> bool:
        """One datagram per sample; True if every one left."""
        ok = True
        for sample in samples:
            try:
                self._sock.sendto(encode_datagram(sample), self._address)
                self.sent += 1
            except OSError:  # no route, a full buffer
                self.failed += 1
                ok = False
        return ok

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self._sock.close()
