"""A CAN bus through python-can, presented as the byte stream every other transport is.

URL: ``can://<interface>/<channel>[?options]``, the interface being any python-can backend by name::

    can://virtual/vscmg                       in-process bus (tests, the lockstep world)
    can://udp_multicast/239.74.163.2?port=43113   across processes on one machine (IPv4 group)
    can://socketcan/can0?fd=1                 a Linux CAN interface, CAN FD
    can://pcan/PCAN_USBBUS1?bitrate=500000    a PEAK adapter at 500 kbit/s
    can://slcan//dev/ttyACM0?bitrate=1000000  a serial-line adapter (the channel is a device path)

=================  ========================================================================
option             meaning
=================  ========================================================================
``node``           the board's node id 0..127 (default 0); host and board use the same one
``fd``             1: CAN FD frames (64 data bytes), 0: classic CAN (default)
``bitrate``        nominal bit rate in bit/s (1..20000000), for hardware interfaces
``data_bitrate``   CAN FD data-phase bit rate in bit/s (1..20000000)
``port``           UDP port (1..65535) of ``udp_multicast`` (python-can's default otherwise)
``send_timeout``   seconds a send may wait for room in the interface's queue (0..60, default 0.1)
=================  ========================================================================

A value outside its range (NaN and the infinities included) is a :class:`TransportRefused` naming the
option, raised when the URL is read: never retried, never handed to python-can. So is a ``udp_multicast``
channel that is no IP multicast group address (a unicast address, a host name, ``239.74.163.2:43113``):
it names the channel.

``fd`` decides what this end sends and which kind it takes; a frame of the other kind is counted
(``rx_wrong_kind``) and logged naming the option — a peer set up with the other ``fd`` — never taken.
``udp_multicast`` is opened for both kinds whatever ``fd`` says: opened classic, python-can drops the CAN
FD frames it receives before this transport sees them, and a peer of the other kind went unheard with
nothing counted.

Other interface settings (a Vector app name, a Kvaser serial number, ...) come from python-can's own
configuration file or environment, which ``can.Bus`` reads for the interface named here; an option this
transport does not know is an error, so a typo never passes silently.

What travels: the protocol's wire bytes, cut by :mod:`protocol.can` (one 11-bit arbitration id per
priority class, direction and node; segments of 7 or 63 bytes). :meth:`write` takes any bytes, splits
them at the 0x00 delimiters and sends each complete frame as its segments (a partial frame waits for the
rest of its bytes); :meth:`read` hands up the wire frames the reassembler completed, so the deframer
above sees exactly what a serial link would give it. Lost and incomplete frames, duplicates and foreign
traffic are counted in :meth:`counters`, never delivered (lost frames — ``rx_malformed``,
``rx_incomplete``, ``rx_spliced`` — also logged, each kind at most once a second, what a burst left
unlogged said by the next read once its second has passed; error and remote frames, ``rx_error_frames``,
logged too, an error frame naming its SocketCAN classes, and told a timed-out handshake by
:meth:`CanTransport.heard_instead`: a bus reporting errors, the board unplugged or at another bit rate); so
is, apart (``rx_same_node``, logged), a frame in this end's own direction and node id that this end did
not send — another node configured with the same node id, which the reassembler ignores like the loopback
of this end's own frames. Where the interface says which socket sent a frame (``udp_multicast``: each node
sends from one of its own), a frame in the peer's direction and node id from a second sender — two boards
at one node id, seen from the host — is counted (``rx_other_sender``), logged and dropped: this end follows
the first sender it hears, and the next once that one has been silent for :data:`PEER_HANDOVER_S` (a
restarted board). A transport closed and opened again (the board client's reconnection) sends from the
port it sent from before, where that is still free, so its peer follows it at once. A host sends towards
the board (``Direction.TO_BOARD``) and accepts the board's direction only; the board's side
(:mod:`firmware_sim.servers.can_server`) is the same class with ``sends=Direction.TO_HOST``.

What the bus itself does wrong is told apart from the bus being gone. Gone — the interface down, the
bus shut down, any other error of python-can's — is a :class:`LinkError` naming the URL (the board
client then closes and reopens the bus); frames already completed in that read are handed up first and
the error raised by the next read. Not gone, counted and logged (at most once a second): a message the
interface received but could not decode (``rx_undecodable``: udp_multicast's datagram from another
program on the group, or one whose ``data`` python-can would take as a size:
:class:`_ScreenedUdpMulticastBus`), and a send refused because the interface's transmit queue is full
(``tx_frames_dropped``: the send timed out, or ENOBUFS/EAGAIN — socketcan's "No buffer space
available"); reopening the bus would not help, and the rest of that frame is not sent (the receiver
counts the partial frame).
"""

from __future__ import annotations

import errno
import ipaddress
import logging
import socket
import struct
import threading
import time
from collections import deque
from dataclasses import asdict, dataclass
from typing import Any

import can
from can.interfaces.udp_multicast import UdpMulticastBus
from can.interfaces.udp_multicast.utils import pack_message, unpack_message

try:
    import msgpack
except ImportError:  # python-can installs it beside itself but on Windows; udp_multicast then refuses to open
    msgpack = None

from protocol.can import MAX_WIRE, NODE_MAX, CanId, CanReassembler, CanSegmenter, Direction, Received
from protocol.errors import LinkError, ProtocolError, TransportError, TransportRefused

from .base import Transport, UrlOptions

logger = logging.getLogger(__name__)

DEFAULT_SEND_TIMEOUT_S = 0.1
_TAKES_BOTH_KINDS = frozenset({"udp_multicast"})
"""Interfaces opened with ``fd=True`` whatever the URL's ``fd`` says: opened ``fd=False``, python-can's
``udp_multicast`` drops every CAN FD frame it receives before anyone sees it, so a peer configured for the
other kind went unheard with nothing counted. Opened for both, it hands them up and the reassembler judges
the kind (``rx_wrong_kind``, logged). What this end *sends* still follows ``fd``."""
MAX_SEND_TIMEOUT_S = 60.0
"""The longest ``send_timeout`` (s): a send held a minute for room in the queue is a bus that is gone. A
value python-can cannot hand its socket (``inf``, 1e308) was an OverflowError out of the handshake."""
MAX_BITRATE = 20_000_000
"""The highest ``bitrate`` / ``data_bitrate`` (bit/s) a URL may give: above CAN FD's data phase (8-12
Mbit/s on today's transceivers), far below what an int handed to a driver would wrap."""
_BUS_OPTION_RANGES: dict[str, tuple[float, float, str]] = {
    "bitrate": (1, MAX_BITRATE, "bit/s"),
    "data_bitrate": (1, MAX_BITRATE, "bit/s"),
    "port": (1, 65535, ""),
}
"""The integer options handed to ``can.Bus`` and their ranges: checked here, so the error names the option
instead of a driver's (or a socket's OverflowError) at open."""
_GROUP_INTERFACES = frozenset({"udp_multicast"})
"""Interfaces whose channel is an IP multicast group (IPv4 224.0.0.0/4 or IPv6 ff00::/8), checked when the
URL is read: python-can's ``udp_multicast`` given anything else (a unicast address, a host name, the group
with ``:port`` appended) failed at open with "could not create or configure socket" or a name-service
error, and the host tried again for the whole outage bound before saying so."""
_DRAIN = 512  # CAN messages taken per read after the first complete frame (bounded work per call)
_TX_FULL = frozenset({errno.ENOBUFS, errno.EAGAIN})
"""errno of a send refused for a full transmit queue (socketcan's ENOBUFS): a dropped frame, the bus there."""
_NO_SUCH_FAMILY = frozenset({errno.EAFNOSUPPORT, errno.EPROTONOSUPPORT})
"""errno of an open refused because this system's kernel has no such socket family or protocol (SocketCAN's
``AF_CAN``/``CAN_RAW`` in a container, WSL or a kernel built without them; IPv6 for an IPv6 group). The
kernel loads a protocol's module itself when a socket asks for it, so no second try will find one: the
host tried again for its whole outage bound and then said only "Address family not supported"."""
_LOG_EVERY_S = 1.0  # a counted drop is logged at most this often (the log line says how many since)
PEER_HANDOVER_S = 0.5
"""Silence (s) after which the sender this end follows in its peer's direction and node id is succeeded by
the next one heard, where the interface names each frame's sender (``udp_multicast``: each node sends from a
socket of its own, :class:`_ScreenedUdpMulticastBus`). A board says something far more often (telemetry at
20 Hz, heartbeats at 5 Hz by default), so a second board at its node id is never followed while it talks; a
restarted board (a new process, on a new socket) takes longer than this to start, and is followed at its
first frame. (A board set to say less than twice a second lets a twin in at each of its pauses: counted and
logged each time the two change places.)"""
_ERROR_CLASSES = (
    (0x001, "transmit timeout"),
    (0x002, "arbitration lost"),
    (0x004, "controller problem"),
    (0x008, "protocol violation"),
    (0x010, "transceiver problem"),
    (0x020, "no acknowledgement"),
    (0x040, "bus off"),
    (0x080, "bus error"),
    (0x100, "controller restarted"),
)
"""SocketCAN's error classes (``linux/can/error.h``: the bits of an error frame's id) by name. An error
frame is the controller saying the bus is in trouble — a frame nobody acknowledged (the board unplugged or
off, the only node on the bus), nodes at different bit rates, a missing terminator — and a bus in such
trouble carries none of the peer's frames: said by name, the operator's "no handshake" has its cause."""
_ERROR_HINT = (
    "the bus reports trouble: no other node acknowledging (the peer unplugged or off), nodes at different "
    "bitrates, or a missing terminator?"
)
_ECHOES = 4096
"""This end's sent segments remembered until their loopback comes back (udp_multicast hears its own
datagrams, in the order sent; the virtual interface does not, and the oldest are then forgotten): a frame
in this end's own direction and node id that is none of them was sent by another node using this node id."""


@dataclass
class CanTxStats:
    """What this end has sent. ``frames_dropped``: a send timed out (the interface queue stayed full),
    so the rest of that frame was not sent; ``not_frames``: written bytes that were not a wire frame."""

    frames_sent: int = 0
    segments_sent: int = 0
    frames_dropped: int = 0
    not_frames: int = 0


def _check_option(url: str, key: str, value: float, lo: float, hi: float, unit: str) -> None:
    """Refuse an option's ``value`` outside ``lo..hi`` (NaN and the infinities included: the bounds are
    finite) with a :class:`TransportRefused` naming the URL and ``key``: opening again cannot mend it."""
    if not lo <= value <= hi:
        shown = repr(value)[:40]
        raise TransportRefused(
            f"{url}: option {key}={shown} is outside {lo:.10g}..{hi:.10g}{' ' + unit if unit else ''}"
        )


def _check_group(url: str, channel: str) -> None:
    """Refuse a ``udp_multicast`` ``channel`` that is no IP multicast group address with a
    :class:`TransportRefused` naming the URL and the channel: no second try will open it."""
    try:
        group = ipaddress.ip_address(channel)
    except ValueError:
        group = None
    if group is None or not group.is_multicast:
        host, colon, port = channel.rpartition(":")
        hint = f" (the port goes in ?port={port})" if colon and port.isdigit() and "." in host else ""
        raise TransportRefused(
            f"{url}: channel {channel[:60]!r} is not an IP multicast group address (IPv4 224.0.0.0/4 or "
            f"IPv6 ff00::/8, e.g. can://udp_multicast/239.74.163.2?port=43113){hint}"
        )


def _no_such_family(exc: BaseException) -> bool:
    """An open error (python-can's, or the socket's own OSError) that says the kernel has no such socket
    family or protocol: permanent on this system, unlike an interface that is down or not plugged in."""
    cause = exc.__cause__ if not isinstance(exc, OSError) else exc
    return isinstance(cause, OSError) and cause.errno in _NO_SUCH_FAMILY


def _errno_said(exc: BaseException) -> str:
    """The OSError behind ``exc`` as its message says it (``[Errno 97] Address family not ...``)."""
    cause = exc if isinstance(exc, OSError) else exc.__cause__
    return str(cause if cause is not None else exc)


def _tx_queue_full(exc: BaseException) -> bool:
    """A python-can send error that says the transmit queue is full (the bus is there)."""
    cause = exc.__cause__
    return getattr(exc, "error_code", None) in _TX_FULL or (
        isinstance(cause, OSError) and cause.errno in _TX_FULL
    )


def _undecodable(exc: BaseException) -> bool:
    """A python-can receive error about one message the interface could not decode (udp_multicast's
    ``could not unpack received message``, raised from the decoder's own error), not about the bus."""
    cause = exc.__cause__
    return isinstance(exc, can.CanError) and cause is not None and not isinstance(cause, OSError)


def _error_classes(msg: object) -> list[str]:
    """The SocketCAN error classes an error frame's id names (:data:`_ERROR_CLASSES`); ``["unspecified"]``
    when it names none (an interface that reports errors without a class: its id 0, or not an integer)."""
    bits = getattr(msg, "arbitration_id", 0)
    if not isinstance(bits, int) or isinstance(bits, bool):
        bits = 0
    return [name for bit, name in _ERROR_CLASSES if bits & bit] or ["unspecified"]


def _id_said(msg: object) -> str:
    """A message's arbitration id for a log line: hexadecimal when it is an integer, else its type."""
    value = getattr(msg, "arbitration_id", None)
    if isinstance(value, int) and not isinstance(value, bool):
        return f"{value:#x}"
    return type(value).__name__


def _kinds(msg: object) -> str:
    """What a message that is not a CAN frame holds, by type only (its repr may itself fail: python-can
    formats a float id with ``:x``)."""
    names = ("arbitration_id", "data", "dlc", "is_extended_id", "is_fd", "is_error_frame", "is_remote_frame")
    return ", ".join(f"{name}: {type(getattr(msg, name, None)).__name__}" for name in names)


class _ScreenedUdpMulticastBus(UdpMulticastBus):
    """python-can's ``udp_multicast`` bus with each datagram screened before python-can builds its Message.

    python-can hands a datagram's ``data`` to ``bytearray()`` before its own check refuses the message: an
    integer there is taken as a size, so one 157-byte datagram saying ``data=500000000`` from any program
    on the group made the host allocate 500 MB of zeros and spend 1.6 s on it (a larger number: all its
    memory). A datagram whose ``data`` is an integer is refused here as python-can refuses one it cannot
    unpack — a ``CanOperationError`` from the reason, counted ``rx_undecodable`` (:func:`_undecodable`).
    Opened through :func:`_open_bus` only, always for both kinds (``_TAKES_BOTH_KINDS``), so python-can's
    dropping of CAN FD frames on a classic bus is not needed here."""

    sender: object = None
    """The address the message :meth:`recv` returned last was sent from: which node sent it, which CAN
    itself never says (:meth:`CanTransport._from_other_sender`). None: none yet, or a node of python-can's
    own ``udp_multicast`` bus (a tool, a test's noisy node), which all send from the group's port and so
    name no one node."""

    sender_port: int = 0
    """The port this node sends from (:meth:`_bind_sender`)."""

    def __init__(self, channel: str, sender_port: int = 0, **options: Any) -> None:
        super().__init__(channel, **options)
        # python-can sends from the socket it receives on, bound to the group's port: every node on a
        # machine then sends from one address, and a second board at this node id could not be told from
        # this one. A socket of its own per node, on an ephemeral port, gives each sender an address.
        multicast = self._multicast
        v4 = multicast.ip_version == 4
        self._tx = socket.socket(socket.AF_INET if v4 else socket.AF_INET6, socket.SOCK_DGRAM)
        try:
            level, option = (
                (socket.IPPROTO_IP, socket.IP_MULTICAST_TTL)
                if v4
                else (socket.IPPROTO_IPV6, socket.IPV6_MULTICAST_HOPS)
            )
            self._tx.setsockopt(level, option, struct.pack("@I", multicast.hop_limit))
            self.sender_port = self._bind_sender(v4, sender_port)
        except OSError as exc:
            self._tx.close()
            super().shutdown()
            raise can.CanInitializationError("could not create or configure socket") from exc

    def _bind_sender(self, v4: bool, port: int) -> int:
        """Bind the sending socket to ``port`` (0: an ephemeral one) and return the port it got. The port a
        closed bus of the same transport sent from, where it is still free: the same end, reopened (the
        board client's reconnection), is then the same sender to its peer — on a new port, the peer took it
        for a second node at its node id and dropped its frames for :data:`PEER_HANDOVER_S`, logging "two
        hosts configured with node id N?". Taken meanwhile by another socket, an ephemeral port."""
        anywhere = "0.0.0.0" if v4 else "::"
        try:
            self._tx.bind((anywhere, port))
        except OSError:
            if not port:
                raise
            self._tx.bind((anywhere, 0))
        return int(self._tx.getsockname()[1])

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """python-can's ``send`` (its errors: ``CanTimeoutError``, ``CanOperationError`` from the OSError),
        from this node's own socket."""
        data = pack_message(msg)
        self._tx.settimeout(timeout)
        try:
            if self._tx.sendto(data, self._multicast._send_destination) < len(data):
                raise TimeoutError()
        except TimeoutError:
            raise can.CanTimeoutError() from None
        except OSError as exc:
            raise can.CanOperationError("failed to send via socket") from exc

    def shutdown(self) -> None:
        self._tx.close()
        super().shutdown()

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        received = self._multicast.recv(timeout)
        if not received:
            return None, False
        datagram, sender, timestamp = received
        # python-can's own bus sends from the group's port: such a sender may be any of its nodes there
        self.sender = None if sender[1] == self._multicast.port else sender
        try:
            fields = msgpack.unpackb(datagram, raw=False)  # at most a datagram's size: nothing allocated
            data = fields.get("data") if isinstance(fields, dict) else None
            if isinstance(data, int):
                raise ValueError(f"its data is the integer {str(data)[:20]}, not bytes")
            return unpack_message(datagram, replace={"timestamp": timestamp}, check=True), False
        except Exception as exc:  # python-can's own wording and cause, so it is counted the same way
            raise can.CanOperationError("could not unpack received message") from exc


def _open_bus(interface: str, channel: str, sender_port: int = 0, **options: Any) -> can.BusABC:
    """``can.Bus(interface=interface, channel=channel, **options)``; ``udp_multicast`` as
    :class:`_ScreenedUdpMulticastBus` sending from ``sender_port`` where it is free (0: any), with the same
    configuration ``can.Bus`` would read for it."""
    if interface != "udp_multicast":
        return can.Bus(interface=interface, channel=channel, **options)
    config = can.util.load_config(config={"interface": interface, "channel": channel, **options})
    del config["interface"]
    return _ScreenedUdpMulticastBus(config.pop("channel"), sender_port=sender_port, **config)


class CanTransport(Transport):
    """The protocol's byte stream over one python-can bus; see the module docstring.

    ``sends`` is this end's direction: a host (the default) sends ``TO_BOARD`` and receives ``TO_HOST``."""

    scheme = "can"

    def __init__(self, url: str, sends: Direction = Direction.TO_BOARD) -> None:
        super().__init__(url)
        opts = UrlOptions(url)
        self.interface = opts.netloc
        self.channel = opts.path[1:]  # the one "/" after the interface separates it from the channel
        if not self.interface or not self.channel:
            raise TransportError(f"{url}: expected can://<interface>/<channel>, e.g. can://virtual/vscmg")
        if self.interface in _GROUP_INTERFACES:
            _check_group(url, self.channel)
        self.node = opts.get_int("node", 0)
        _check_option(url, "node", self.node, 0, NODE_MAX, "")
        self.fd = opts.get_bool("fd", False)
        self.send_timeout = opts.get_float("send_timeout", DEFAULT_SEND_TIMEOUT_S)
        _check_option(url, "send_timeout", self.send_timeout, 0.0, MAX_SEND_TIMEOUT_S, "s")
        self._bus_options: dict[str, Any] = {}
        for key, (lo, hi, unit) in _BUS_OPTION_RANGES.items():
            if opts.get(key) is not None:
                self._bus_options[key] = opts.get_int(key, 0)
                _check_option(url, key, self._bus_options[key], lo, hi, unit)
        opts.finish()
        self.sends = Direction(sends)
        receives = Direction.TO_HOST if self.sends is Direction.TO_BOARD else Direction.TO_BOARD
        self._segmenter = CanSegmenter(self.node, self.sends, self.fd)
        self._reassembler = CanReassembler(self.node, receives, fd=self.fd)
        self._out = bytearray()
        self.tx = CanTxStats()
        self.undecodable = 0  # messages the interface received but could not decode
        self.same_node = 0  # CAN frames as this end (its direction, its node id) that it did not send
        self._receives = receives
        # frames towards this end from other node ids (node id -> count; at most NODE_MAX + 1 keys): a peer
        # set up with another ``node`` option is heard only so, and told by heard_instead
        self._other_nodes: dict[int, int] = {}
        self.other_sender = 0  # frames in the peer's direction and node id from a second sender (dropped)
        self._source: object = None  # the sender of the message _recv returned last (None: not said)
        self._peer: object = None  # the sender followed in the peer's direction and node id
        self._peer_heard_at = 0.0  # when it was last heard (s, the frames' receive clock)
        self._invalid_seen = 0  # the reassembler's ``invalid`` count when this end last looked
        self._error_frames_seen = 0  # the reassembler's ``error_frames`` count when this end last looked
        # error frames by class and remote frames ("remote") heard: at most len(_ERROR_CLASSES) + 2 keys
        self._bus_trouble: dict[str, int] = {}
        self._losses_seen = (0, 0, 0)  # its malformed, incomplete and spliced counts when last logged
        self._unechoed: deque[tuple[int, bytes]] = deque()  # sent, loopback not yet heard (<= _ECHOES)
        self._unechoed_count: dict[tuple[int, bytes], int] = {}  # how many of each the deque holds
        self._echo_lock = threading.Lock()  # the writer appends, the reader takes the loopback off
        self._bus: can.BusABC | None = None
        # the port this end sends from where the interface names senders (udp_multicast; 0: none yet), kept
        # for the next open so that a reopened end is the same sender to its peer (_bind_sender)
        self._sender_port = 0
        self._skipped = False  # the last _recv returned None for an undecodable message, not a timeout
        self._logged_at: dict[str, float] = {}  # when each kind of counted drop was last logged
        self._unlogged: dict[str, int] = {}  # drops of each kind counted since its last line, not yet said
        self._unlogged_said: dict[str, str] = {}  # the latest of them, as _log_drop would have said it

    # ------------------------------------------------------------------ backend
    def _open_impl(self) -> None:
        fd = self.fd or self.interface in _TAKES_BOTH_KINDS
        try:
            self._bus = _open_bus(
                self.interface, self.channel, fd=fd, sender_port=self._sender_port, **self._bus_options
            )
            self._sender_port = getattr(self._bus, "sender_port", 0)
        except (ImportError, NotImplementedError) as exc:  # no such interface here: trying again cannot help
            raise TransportRefused(
                f"{self.url}: python-can has no {self.interface!r} interface here: {exc}"
            ) from exc
        except (can.CanError, OSError) as exc:
            if _no_such_family(exc):  # no kernel support: trying again cannot help
                socketcan = self.interface == "socketcan"
                hint = "; SocketCAN needs Linux's can and can_raw modules" if socketcan else ""
                raise TransportRefused(
                    f"{self.url}: this system cannot open a {self.interface!r} CAN bus: its kernel has no "
                    f"such socket family ({_errno_said(exc)}{hint})"
                ) from exc
            if not isinstance(exc, can.CanError):
                raise  # Transport.open's: a device not there (yet), tried again
            # an interface down or not plugged in yet: tried again
            raise TransportError(
                f"{self.url}: cannot open the {self.interface!r} CAN interface: {exc}"
            ) from exc

    def _read(self, timeout: float | None) -> bytes:
        deadline = None if timeout is None else time.monotonic() + timeout
        out = bytearray()
        taken = 0
        try:
            while not out:  # wait for the first complete frame (or the deadline)
                wait = None if deadline is None else max(deadline - time.monotonic(), 0.0)
                msg = self._recv(wait)
                if msg is None and not self._skipped:
                    return b""
                if msg is not None:
                    out += self._accept(msg)
                taken += 1
                if wait == 0.0 and taken >= _DRAIN:
                    break
            for _ in range(_DRAIN):  # then whatever else is already queued
                msg = self._recv(0.0)
                if msg is not None:
                    out += self._accept(msg)
                elif not self._skipped:
                    break
        except LinkError as exc:  # the frames completed before the failure are handed up first
            return self._hand_up_then_fail(out, exc)
        finally:  # after this read's own drops: one of a kind held back says the count in its own line
            self._log_unlogged()
        return bytes(out)

    def _write(self, data: bytes) -> None:
        buf = self._out
        buf += data
        while (end := buf.find(0)) >= 0:
            wire = bytes(buf[: end + 1])
            del buf[: end + 1]
            if len(wire) > 1:  # a lone 0x00 is idle fill
                self._send_frame(wire)
        if len(buf) > MAX_WIRE:  # no delimiter within a frame's length: not protocol bytes
            self._not_a_frame(len(buf), "without a delimiter")
            buf.clear()

    def _close(self) -> None:
        bus, self._bus = self._bus, None
        self._out.clear()
        with self._echo_lock:
            self._unechoed.clear()
            self._unechoed_count.clear()
        self._reassembler.reset()  # partial frames die with the connection (counted as cut)
        self._peer = self._source = None  # a reopened bus follows whichever peer it hears first
        if bus is not None:
            try:
                bus.shutdown()
            except (can.CanError, OSError) as exc:  # shutting down a vanished interface
                logger.debug("%s: shutdown: %s", self.url, exc)

    # ------------------------------------------------------------------ inspection
    def counters(self) -> dict[str, int]:
        """Reassembly (``rx_*``) and transmit (``tx_*``) counters, for link statistics."""
        rx = {f"rx_{k}": v for k, v in asdict(self._reassembler.stats).items()}
        tx = {f"tx_{k}": v for k, v in asdict(self.tx).items()}
        return {
            **rx,
            "rx_undecodable": self.undecodable,
            "rx_same_node": self.same_node,
            "rx_other_sender": self.other_sender,
            **tx,
        }

    # ------------------------------------------------------------------ internals
    def _recv(self, timeout: float | None) -> can.Message | None:
        """The next message, or None: none within ``timeout``, or one the interface could not decode
        (counted; ``self._skipped`` says which)."""
        bus = self._bus
        if bus is None:  # closed by another thread under this read
            raise LinkError(f"{self.url}: the CAN bus was closed during a read")
        self._skipped = False
        try:
            msg = bus.recv(timeout)
            self._source = getattr(bus, "sender", None)
            return msg
        except (can.CanError, OSError) as exc:
            if _undecodable(exc):
                self.undecodable += 1
                self._skipped = True
                self._log_drop("rx", f"a received CAN message could not be decoded ({exc.__cause__!r})")
                return None
            raise LinkError(f"{self.url}: receive failed (interface gone?): {exc}") from exc

    def _accept(self, msg: can.Message) -> bytes:
        reassembler = self._reassembler
        fields = reassembler.admit(msg)  # never raises: a message whose fields are not a frame's is counted
        if fields is None:
            if reassembler.stats.invalid != self._invalid_seen:
                self._invalid_seen = reassembler.stats.invalid
                self._log_drop(
                    "invalid", f"a received CAN message whose fields are not a CAN frame's ({_kinds(msg)})"
                )
            if reassembler.stats.error_frames != self._error_frames_seen:
                self._error_frames_seen = reassembler.stats.error_frames
                self._note_bus_trouble(msg)
            return b""
        self._note_other_node(fields)
        if self._impersonated(fields):
            self.same_node += 1
            peer, twins = ("board", "hosts") if self.sends is Direction.TO_BOARD else ("host", "boards")
            self._log_drop(
                "same_node",
                f"a CAN frame as this end (node {self.node}, towards the {peer}) that it did not send: "
                f"another node uses node id {self.node} — two {twins} on one node?",
            )
        if self._from_other_sender(fields):
            return b""
        stats = reassembler.stats
        wrong_kind = stats.wrong_kind
        out = reassembler.feed(*fields)
        if (stats.malformed, stats.incomplete, stats.spliced) != self._losses_seen:
            self._log_losses()
        if stats.wrong_kind != wrong_kind:
            self._log_drop("wrong_kind", self._wrong_kind_said(stats.wrong_kind - wrong_kind))
        return out

    def _wrong_kind_said(self, n: int) -> str:
        """``n`` frames of the other kind than this end's, said naming the option that decides it."""
        theirs, ours = ("CAN FD", "classic") if not self.fd else ("classic CAN", "CAN FD")
        return (
            f"{n} {theirs} frame(s) on this {ours} link (fd={int(self.fd)}; rx_wrong_kind): a peer set up "
            f"with fd={int(not self.fd)}? Both ends need the same fd option"
        )

    def heard_instead(self) -> str:
        """What this transport heard instead of its peer, said for the operator (empty if nothing): frames
        of the other kind (a board with another ``fd`` option), and frames towards this end from other
        node ids (a board with another ``node`` option: the handshake's timeout said only "no handshake",
        though the board's own frames were on the bus, every one counted ``rx_ignored``), and the error
        frames (by class) and remote frames the bus carried instead (a board unplugged, a bit-rate
        mismatch: the bus reports errors, and no frame of the board's arrives)."""
        said = self._bus_trouble_said()
        n = self._reassembler.stats.wrong_kind
        if n > 0:
            said += f"; {self._wrong_kind_said(n)}"
        if self._other_nodes:
            peer = "board" if self.sends is Direction.TO_BOARD else "host"
            nodes = sorted(self._other_nodes.items(), key=lambda item: -item[1])[:4]
            heard = ", ".join(f"node {node} ({count} frames)" for node, count in nodes)
            said += (
                f"; heard a {peer} on this bus as {heard}, not node {self.node}: both ends need the same "
                "node option"
            )
        return said

    def _note_bus_trouble(self, msg: object) -> None:
        """An error frame or a remote frame (counted ``rx_error_frames`` by the reassembler): tallied by
        kind for :meth:`heard_instead` and logged (at most once a second per kind). Counted only, a bus
        reporting nothing but errors — the board unplugged, a bit-rate mismatch — left both ends' logs
        silent and the handshake's timeout saying only "no handshake"."""
        if getattr(msg, "is_error_frame", False):
            classes = _error_classes(msg)
            for name in classes:
                self._bus_trouble[name] = self._bus_trouble.get(name, 0) + 1
            self._log_drop(
                "error_frame", f"a CAN error frame ({', '.join(classes)}): {_ERROR_HINT} (rx_error_frames)"
            )
        else:
            self._bus_trouble["remote"] = self._bus_trouble.get("remote", 0) + 1
            self._log_drop(
                "remote_frame",
                f"a CAN remote frame (RTR, id {_id_said(msg)}), which this protocol never sends: a node of "
                "another protocol on this bus? (rx_error_frames)",
            )

    def _bus_trouble_said(self) -> str:
        """The error and remote frames heard, by kind, most first ("" if none)."""
        if not self._bus_trouble:
            return ""
        remote = self._bus_trouble.get("remote", 0)
        errors = sorted(((n, k) for k, n in self._bus_trouble.items() if k != "remote"), reverse=True)
        said = ""
        if errors:
            kinds = ", ".join(f"{name} x{n}" for n, name in errors)
            said += f"; the bus reported CAN error frames ({kinds}): {_ERROR_HINT}"
        if remote:
            said += f"; heard {remote} CAN remote frame(s), which this protocol never sends"
        return said

    def _note_other_node(self, fields: Received) -> None:
        """Count a data frame towards this end (``receives``) from a node id other than this end's."""
        if fields.is_extended_id:
            return
        try:
            cid = CanId.parse(fields.arbitration_id)
        except ProtocolError:
            return
        if cid.direction is self._receives and cid.node != self.node:
            self._other_nodes[cid.node] = self._other_nodes.get(cid.node, 0) + 1

    def _log_losses(self) -> None:
        """Log the reassembler's lost frames since it was last looked at, each kind at most once a second:
        segments that cannot be one (``rx_malformed``), partial frames given up (``rx_incomplete``) and
        frames joined across a transfer-id wrap (``rx_spliced``). Counted only, a bus that loses frames (a
        second sender on the board's ids, a noisy cable) said nothing in either end's log."""
        stats = self._reassembler.stats
        seen = self._losses_seen
        self._losses_seen = (stats.malformed, stats.incomplete, stats.spliced)
        for kind, what, before, now in (
            ("malformed", "CAN frame(s) that cannot be a segment (rx_malformed)", seen[0], stats.malformed),
            (
                "incomplete",
                "partial frame(s) given up: a segment lost or conflicting, or the sender moved on "
                "(rx_incomplete)",
                seen[1],
                stats.incomplete,
            ),
            (
                "spliced",
                "frame(s) joined from two across a transfer-id wrap, failing the CRC (rx_spliced)",
                seen[2],
                stats.spliced,
            ),
        ):
            if now > before:
                self._log_drop(kind, f"{now - before} {what}", now - before)

    def _impersonated(self, fields: Received) -> bool:
        """A data frame (checked: :meth:`CanReassembler.admit`) in this end's own direction and node id but
        not one it sent (nor the loopback of one: udp_multicast hears its own datagrams). Such a frame is
        ignored by the reassembler like any other of that direction, but it means a second node on the bus
        answers to this node id: both boards would take the host's commands, and the host would hear two
        boards' telemetry interleaved as one board resetting again and again. Counted and logged, so that
        the status of either node names the cause."""
        if fields.is_extended_id:
            return False
        try:
            cid = CanId.parse(fields.arbitration_id)
        except ProtocolError:
            return False
        if cid.node != self.node or cid.direction is not self.sends:
            return False
        key = (fields.arbitration_id, fields.data)
        with self._echo_lock:
            if not self._unechoed_count.get(key):  # a dict look-up, not a scan of up to _ECHOES segments
                return True
            # Our own, looped back: the oldest remembered copy of it. The ones sent before it will not
            # come back now. Each remembered segment is taken off once, so this is constant per segment.
            while True:
                taken = self._forget_oldest_echo()
                if taken == key:
                    break
        return False

    def _from_other_sender(self, fields: Received) -> bool:
        """A data frame in the peer's direction and node id from another sender than the one this end
        follows: counted (``rx_other_sender``), logged and dropped. CAN names no sender, so two boards (or
        two hosts) configured with one node id send the same arbitration ids, and their frames, taken
        alike, reached the session as one board's: its telemetry interleaved with the twin's, boot ids
        flipping back and forth as hundreds of "resets" and re-arms, and nothing named the cause. Where the
        interface says who sent each frame (``udp_multicast``) this end follows the first sender it hears —
        never merging another's frames — and the next one once that sender has been silent for
        :data:`PEER_HANDOVER_S` (a restarted board). Elsewhere (``_source`` None) all are taken: the twin
        then shows as resets, and the twin itself logs ``rx_same_node``."""
        source = self._source
        if source is None or fields.is_extended_id:
            return False
        try:
            cid = CanId.parse(fields.arbitration_id)
        except ProtocolError:
            return False
        if cid.node != self.node or cid.direction is not self._receives:
            return False
        at = fields.at if fields.at is not None else time.time()  # udp_multicast's receive time, wall clock
        silence = at - self._peer_heard_at
        if source == self._peer:
            self._peer_heard_at = max(at, self._peer_heard_at)
            return False
        other = self._peer is not None
        # abs: a wall clock stepped back must not keep a silent sender followed until it catches up
        if other and abs(silence) <= PEER_HANDOVER_S:
            self.other_sender += 1
            peer = "board" if self.sends is Direction.TO_BOARD else "host"
            self._log_drop(
                "other_sender",
                f"a CAN frame from a second {peer} at node {self.node} ({source}; following {self._peer}): "
                f"two {peer}s configured with node id {self.node}? Its frames are never merged "
                "(rx_other_sender)",
            )
            return True
        if other:
            logger.info(
                "%s: following a new sender at node %d (%s), the last one silent for %.1f s",
                self.url,
                self.node,
                source,
                silence,
            )
        self._peer, self._peer_heard_at = source, at
        return False

    def _remember_echo(self, key: tuple[int, bytes]) -> None:
        """Remember a segment about to be sent until its loopback comes back (the caller holds
        ``_echo_lock``). The deque keeps their order, the count beside it answers "is this one of ours?"
        without a scan: every frame in this end's own direction and node id asks, under the lock the writer
        takes too, and a linear look-up over 4096 segments cost each such frame ~20x any other."""
        if len(self._unechoed) >= _ECHOES:
            self._forget_oldest_echo()  # the virtual interface never loops back: the oldest are forgotten
        self._unechoed.append(key)
        self._unechoed_count[key] = self._unechoed_count.get(key, 0) + 1

    def _forget_oldest_echo(self) -> tuple[int, bytes]:
        """Take the oldest remembered segment off the deque and its count (the caller holds the lock)."""
        key = self._unechoed.popleft()
        left = self._unechoed_count[key] - 1
        if left:
            self._unechoed_count[key] = left
        else:
            del self._unechoed_count[key]
        return key

    def _log_drop(self, kind: str, what: str, count: int = 1) -> None:
        """Log a counted drop (``count`` of them) at most once a second per kind, saying how many went
        unlogged since."""
        now = time.monotonic()
        last = self._logged_at.get(kind)
        if last is not None and now - last < _LOG_EVERY_S:
            self._unlogged[kind] = self._unlogged.get(kind, 0) + count
            self._unlogged_said[kind] = what
            return
        self._logged_at[kind] = now
        more = self._unlogged.pop(kind, 0)
        self._unlogged_said.pop(kind, None)
        logger.warning("%s: %s; dropped%s", self.url, what, f" ({more} more since)" if more else "")

    def _log_unlogged(self) -> None:
        """Log the drops held back by :meth:`_log_drop`'s once-a-second rate once their kind's second has
        passed (each read looks, as it ends). Said only with the next drop of the same kind, a burst — 10 000
        malformed frames in half a second, then quiet — left one line saying "1 ... dropped" and the rest
        in the counters alone: the log told of one lost frame."""
        if not self._unlogged:
            return
        now = time.monotonic()
        for kind in list(self._unlogged):
            if now - self._logged_at.get(kind, now) < _LOG_EVERY_S:
                continue
            more = self._unlogged.pop(kind)
            what = self._unlogged_said.pop(kind, kind)
            self._logged_at[kind] = now
            logger.warning(
                "%s: %d more dropped since the last such line, the latest: %s", self.url, more, what
            )

    def _send_frame(self, wire: bytes) -> None:
        bus = self._bus
        if bus is None:  # closed by another thread under this write
            raise LinkError(f"{self.url}: the CAN bus was closed during a write")
        try:
            segments = self._segmenter.segment(wire)
        except ProtocolError as exc:
            self._not_a_frame(len(wire), str(exc))
            return
        for seg in segments:
            msg = can.Message(
                arbitration_id=seg.arbitration_id,
                data=seg.data,
                is_fd=seg.is_fd,
                bitrate_switch=seg.is_fd and "data_bitrate" in self._bus_options,
                is_extended_id=False,
            )
            with self._echo_lock:  # before the send: its loopback may be read before send returns
                self._remember_echo((seg.arbitration_id, seg.data))
            try:
                bus.send(msg, timeout=self.send_timeout)
            except (can.CanError, OSError) as exc:
                if not (isinstance(exc, can.CanTimeoutError) or _tx_queue_full(exc)):
                    raise LinkError(f"{self.url}: send failed (interface gone?): {exc}") from exc
                self.tx.frames_dropped += 1  # the receiver discards the partial frame and counts it
                self._log_drop("tx", f"CAN transmit queue full ({str(exc) or type(exc).__name__}): a frame")
                return
            self.tx.segments_sent += 1
        self.tx.frames_sent += 1

    def _not_a_frame(self, size: int, why: str) -> None:
        self.tx.not_frames += 1
        logger.warning("%s: %d written bytes are not a wire frame (%s); not sent", self.url, size, why)
