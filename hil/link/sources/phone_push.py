"""Live phone samples over HTTP: the Sensor Logger app's "HTTP Push" stream, received and sent.

The app (Kelvin Choi's *Sensor Logger*, Android and iOS, www.tszheichoi.com/sensorlogger — the same app
whose CSV export ``hil replay`` reads) POSTs, once per configurable batch period, one JSON object per
batch to a URL the user enters in *Settings → Data Streaming → HTTP Push*::

    {"messageId": 12, "sessionId": "…", "deviceId": "…",
     "payload": [{"name": "gyroscope", "time": 1698501144401773000,
                  "values": {"x": 0.01, "y": -0.02, "z": 0.003}}, …]}

``time`` is UTC epoch nanoseconds of each reading (every sensor keeps its own timestamps, so the rate
mismatch survives the batching). Names used here: ``totalacceleration`` (m/s², gravity included — what
the estimator wants; Sensor Logger's ``accelerometer`` is the user acceleration *without* gravity, and is
used only together with ``gravity`` from the same batch), ``gyroscope`` (rad/s), ``magnetometer`` (µT),
all in the Android sensor frame (x screen right, y screen up, z out of the screen). Entries of other
sensors are ignored (counted). The raw types the app pushes when they are enabled
(``gyroscopeuncalibrated``, ``magnetometeruncalibrated``, ``accelerometeruncalibrated``: :data:`UNCALIBRATED`)
stand in for a sensor whose calibrated type the stream has not sent — as the CSV export's
``…Uncalibrated.csv`` files and SensaGram's uncalibrated types do — and are ignored and counted from its
first calibrated reading on (the app always pushes the calibrated ones beside them; two sensors' readings
are never interleaved as one), until that calibrated type has been silent for
:data:`~.stream.CALIBRATED_QUIET_S` (turned off in the app mid-run: counted, ``calibrated_lapses``, and
logged; the raw type is read again). Total acceleration holds the accelerometer over the user acceleration
and gravity the same way. Set the app's batch period as short as it allows: the batch period is
added to the control loop's sensing latency.

**One phone.** A batch's sender is its app's ``deviceId`` and ``sessionId`` (one recording of one phone;
a batch with neither: the peer's address — a TCP connection's port changes as the app reconnects, so it
names no sender). The receiver follows the first sender heard with a reading the host uses; every other
sender's batches are answered 200 (an app that saw errors might stop pushing) and dropped, counted and
logged, never merged — two Sensor Logger phones on one network both stamp Unix ns, so their readings would
pass for one phone's. The app restarted (a new ``sessionId``) is followed once its old session has been
silent for :data:`~.senders.SWITCH_AFTER_S` (or four of its batch periods, if longer); a phone that pushed
alongside the followed one never is (:mod:`.senders`: the rule and why). Nothing authenticates a phone: any
peer can send any ``deviceId``.

:class:`PhonePushServer` is the receiving end (the host); :class:`PhonePushSender` is the sending end
(the emulator's simulated phone, which streams to the host exactly as the app would). Parsing is a pure
function, :func:`decode_push`, so it is tested without sockets.
"""

from __future__ import annotations

import hashlib
import http.client
import json
import logging
import math
import threading
import time
from collections import Counter, OrderedDict
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any
from urllib.parse import urlsplit

from hil.estimation.sensors import SensorKind, SensorSample
from hil.link.sources.http_guard import BodyError, GuardedHandler, GuardedHTTPServer, HttpLimits
from hil.link.sources.push_decoder import DECODE_TIMEOUT_S, Decoded, PushDecoder
from hil.link.sources.senders import MAX_SENDERS, Decision
from hil.link.sources.stream import MAX_BATCH, MAX_QUEUE, PhoneReceiver, parse_json, reading_number, split_url
from protocol.errors import InputFormatError, LinkError

logger = logging.getLogger(__name__)

NAMES: dict[str, SensorKind] = {
    "totalacceleration": SensorKind.ACC,
    "gyroscope": SensorKind.GYR,
    "magnetometer": SensorKind.MAG,
}
_NAME_OF = {kind: name for name, kind in NAMES.items()}
UNCALIBRATED: dict[str, SensorKind] = {
    "accelerometeruncalibrated": SensorKind.ACC,
    "gyroscopeuncalibrated": SensorKind.GYR,
    "magnetometeruncalibrated": SensorKind.MAG,
}
"""Sensor Logger's raw ("Uncalibrated") types, pushed when the user enables them: ``values`` x, y, z the
raw reading (any bias keys beside them unread, as the CSV export's bias columns are). Used only while the
stream has not sent that sensor's calibrated type (:func:`decode_push`'s ``calibrated``)."""
G = 9.80665
"""m/s² per g: iOS's raw accelerometer reads in g."""
MAX_BODY = 4 * 1024 * 1024  # bytes: a batch larger than this is refused (413), not buffered
REQUEST_TIMEOUT_S = 10.0  # s: from waiting for a request to its last byte (an idle keep-alive ends here)
MAX_CONNECTIONS = 8  # served at once; the app keeps one
INLINE_MAX = 64 * 1024
"""bytes: a push up to this size (~800 readings; the app's 20 ms batch is ~1 kB) is decoded in the server's
handler thread — ~1 ms of json.loads holding the interpreter's lock, a few ms of Python that yields it;
larger ones in the decoder process (:mod:`.push_decoder`), so that no push can stall the control loop."""
MAX_MESSAGE_GAP = 100_000
"""batches: a jump in ``messageId`` at most this far counts the batches between as lost (``message_gaps``:
at the app's 20 ms period, over half an hour of them). A farther jump is not losses but a numbering of
another's — a client's own ids, a hostile ``10**4000`` — and starts the count again
(``message_restarts``), as a jump back does: counted as lost, one id of ``10**4299`` made ``message_gaps`` an
integer of 4300 digits, and two such made ``summary.json`` unwritable (past Python's digit limit)."""
LATE_WINDOW = 256
"""batches: how far behind the newest ``messageId`` a batch may arrive and still be told apart as late (an
HTTP retry, a batch overtaken on a second connection: counted lost when the numbering jumped past it, and
uncounted when it comes) or as a retry of one received, rather than as the numbering started again (5 s of
the app's 20 ms batches; :class:`MessageNumbering`)."""
MAX_NUMBERINGS = 8
"""``messageId`` numberings remembered per peer address for the batches that carry no ``deviceId`` or
``sessionId`` (:class:`PeerNumberings`): two or three clients behind one address, with room to spare; the
least recently heard forgotten first."""
MAX_ID = 64
"""characters of a ``deviceId`` or ``sessionId`` kept as they are (the app's are UUIDs, 36); a longer one is
kept as its start and a digest of the whole, so that what a sender is called stays small, and two long ids
with one start stay two senders."""


_Timed = tuple[float, tuple[float, float, float]]


OTHER_PHONE = "not used: this receiver follows another phone"
"""The answer (200) to a batch of another phone than the one followed: dropped, counted."""


class MessageNumbering:
    """One stream's ``messageId`` numbering, for counting the batches lost in transit: a jump forward of at
    most :data:`MAX_MESSAGE_GAP` counts the ids between as lost (``gaps``); one of them arriving late (within
    :data:`LATE_WINDOW` of the newest: an HTTP retry) is uncounted, an id received already is a retry; any
    other id back, or a farther jump, is the numbering started again (``restarts``). Without the window a
    batch overtaken by the next (ids 1, 2, 4, 3, 5) counted two lost and a restart, none lost.

    Memory is bounded: the ids counted lost are remembered only within :data:`LATE_WINDOW` of the newest."""

    def __init__(self) -> None:
        self.newest: int | None = None
        self._start = 0  # the first id of this numbering: below it is no retry of ours
        self._missing: dict[int, None] = {}  # ids counted lost within LATE_WINDOW, ascending

    def hear(self, message_id: int) -> tuple[int, int]:
        """One batch's id: ``(lost, restarts)``, the change it makes to the stream's counts (``lost`` is
        negative for a batch that was counted lost and came late)."""
        newest = self.newest
        if newest is None:
            self._restart(message_id)
            return 0, 0
        jump = message_id - newest - 1
        if 0 <= jump <= MAX_MESSAGE_GAP:
            self.newest = message_id
            for lost in range(max(newest + 1, message_id - LATE_WINDOW), message_id):
                self._missing[lost] = None
            floor = message_id - LATE_WINDOW
            while self._missing and next(iter(self._missing)) < floor:  # ascending: the oldest first
                del self._missing[next(iter(self._missing))]
            return jump, 0
        if max(self._start, newest - LATE_WINDOW) <= message_id <= newest:
            if message_id in self._missing:  # counted lost, and here it is
                del self._missing[message_id]
                return -1, 0
            return 0, 0  # received already: a retry, its samples the admission's duplicates
        self._restart(message_id)
        return 0, 1

    def _restart(self, message_id: int) -> None:
        self.newest = self._start = message_id
        self._missing.clear()

    def continues(self, message_id: int) -> int | None:
        """How far ``message_id`` is from this numbering's newest if it is near enough to be of it (late or
        ahead by at most :data:`LATE_WINDOW`: a client silent for longer is heard anew anyway), else None."""
        if self.newest is None or not -LATE_WINDOW <= message_id - self.newest <= LATE_WINDOW + 1:
            return None
        return abs(message_id - self.newest)


class PeerNumberings:
    """Which client behind one address a batch without ``deviceId`` and ``sessionId`` is, by its
    ``messageId``: each client numbers its own batches, so two behind one address (two phones on one NAT'd
    Wi-Fi, two scripts on one laptop) are two numberings — a batch is the numbering it continues
    (:meth:`MessageNumbering.continues`, the nearest), or starts one. Keyed by them, the two are two
    senders (:mod:`.senders`: the second dropped, counted, never merged); merged, their readings were
    interleaved into one stream. A client that restarts its numbering, or jumps it by more than
    :data:`LATE_WINDOW` (5 s of 20 ms batches lost: silent past the one-phone rule's bound), is a new
    sender too, followed once the old numbering is silent (:data:`~.senders.SWITCH_AFTER_S`), as an app's
    new ``sessionId`` is. Two clients whose numberings are within :data:`LATE_WINDOW` of each other (started
    within ~5 s of each other) cannot be told apart by it: they are merged, as before.

    Memory is bounded: :data:`MAX_NUMBERINGS` per address, and :data:`~.senders.MAX_SENDERS` addresses,
    the least recently heard forgotten first. Not thread-safe: the server calls it under its lock."""

    def __init__(self) -> None:
        self._peers: OrderedDict[str, OrderedDict[int, MessageNumbering]] = OrderedDict()
        self._next = 0  # numberings are numbered in the order heard (names for the log)

    def which(self, peer: str, message_id: int) -> int:
        """The number of the numbering of ``peer`` that ``message_id`` continues (started if none)."""
        numberings = self._peers.setdefault(peer, OrderedDict())
        self._peers.move_to_end(peer)
        while len(self._peers) > MAX_SENDERS:
            self._peers.popitem(last=False)
        near = [(d, n) for n, known in numberings.items() if (d := known.continues(message_id)) is not None]
        if near:
            number = min(near)[1]
        else:
            number, self._next = self._next, self._next + 1
            numberings[number] = MessageNumbering()
            while len(numberings) > MAX_NUMBERINGS:
                numberings.popitem(last=False)
        numberings.move_to_end(number)
        numbering = numberings[number]
        if numbering.newest is None or message_id > numbering.newest:
            numbering.newest = message_id  # only its place is followed here: the stream counts its gaps
        return number


def _address(url: str) -> tuple[str, int, str]:
    return split_url(url, "http", "http://HOST:PORT/PATH", default_port=80)


@dataclass(frozen=True)
class PushBatch:
    """One HTTP Push batch, decoded: its ``samples`` (time order, seconds since the epoch), its entries
    that could not be used (``bad``) and those of other sensors or not needed (``ignored``), the app's
    ``messageId`` (None: none or not an integer), whether it held total acceleration (``total``), and
    its ``deviceId`` and ``sessionId`` (None: none, or not a string; a long one shortened: :func:`app_id`)."""

    samples: list[SensorSample]
    bad: int
    ignored: int
    message_id: int | None
    total: bool
    device: str | None = None
    session: str | None = None
    calibrated: frozenset[SensorKind] = frozenset()  # the sensors whose calibrated type the batch held


def app_id(value: object) -> str | None:
    """A ``deviceId`` or ``sessionId`` as the receiver keeps it: the string itself up to :data:`MAX_ID`
    characters, a longer one as its start and a digest of the whole; None when it is not a string."""
    if not isinstance(value, str):
        return None
    if len(value) <= MAX_ID:
        return value
    digest = hashlib.blake2b(value.encode("utf-8", "surrogatepass"), digest_size=8).hexdigest()
    return f"{value[: MAX_ID - 20]}…{digest}"


def decode_push(
    body: bytes, source: str = "push", *, parts: bool = True, calibrated: Iterable[SensorKind] = ()
) -> PushBatch:
    """Parse one HTTP Push batch into samples (time-ordered per sensor, seconds since the epoch).

    A body that is not a JSON object with a ``payload`` list raises :class:`InputFormatError` naming
    ``source`` — whatever the bytes, nothing else is raised; a reading that cannot be used is counted in
    ``bad``. The batch's ``time`` unit is the app's ns unless its readings say otherwise
    (:func:`time_unit`). ``parts``: whether the user acceleration and gravity of a batch without total
    acceleration make its accelerometer; a stream that has sent total acceleration keeps it as its one
    accelerometer (:class:`PhonePushServer`: its later batches' parts are ignored, counted), so that two
    sensors' readings are never interleaved as one (a 20 ms batch often holds no reading of a ~50 Hz
    sensor). ``calibrated``: the sensors whose calibrated type the stream has sent (the accelerometer's:
    total acceleration, or the parts); their raw types (:data:`UNCALIBRATED`) are ignored, counted, as are
    those of a sensor whose calibrated type this batch holds; the others are read as that sensor — a raw
    accelerometer whose median norm in the batch is 0.5-2 as in g (iOS's), converted to m/s² (as the CSV
    export's ``AccelerometerUncalibrated.csv`` is).
    """
    doc = parse_json(body, source)
    if not isinstance(doc, dict) or not isinstance(doc.get("payload"), list):
        raise InputFormatError("expected a JSON object with a 'payload' list", source)
    message_id = doc.get("messageId")
    message_id = message_id if isinstance(message_id, int) and not isinstance(message_id, bool) else None
    bad = ignored = 0
    readings: list[tuple[str, int | float, tuple[float, float, float]]] = []
    for entry in doc["payload"]:
        name = entry.get("name") if isinstance(entry, dict) else None
        if not isinstance(name, str):
            bad += 1
            continue
        name = name.strip().lower()  # as the UDP decoder reads a type: a client may pad or capitalise it
        if name not in NAMES and name not in UNCALIBRATED and name not in ("accelerometer", "gravity"):
            ignored += 1
            continue
        reading = _reading(entry)
        if reading is None:
            bad += 1
            continue
        readings.append((name, *reading))
    ns_per_unit = time_unit(readings)
    samples: list[SensorSample] = []
    gravity: list[_Timed] = []
    user_acc: list[_Timed] = []
    raw_readings: dict[SensorKind, list[_Timed]] = {}
    have_total = False
    for name, raw, xyz in readings:
        t = _seconds(raw, ns_per_unit)
        if not math.isfinite(t):  # a float time finite in ns, past a float's range in the batch's unit
            bad += 1
            continue
        if name == "accelerometer":
            user_acc.append((t, xyz))
        elif name == "gravity":
            gravity.append((t, xyz))
        elif name in UNCALIBRATED:
            raw_readings.setdefault(UNCALIBRATED[name], []).append((t, xyz))
        else:
            have_total |= NAMES[name] is SensorKind.ACC
            samples.append(SensorSample(t, NAMES[name], xyz))
    if parts and not have_total and user_acc and gravity:
        total = _total_from_parts(user_acc, gravity)
        finite = [s for s in total if all(math.isfinite(v) for v in s.xyz)]
        bad += len(total) - len(finite)  # finite parts whose sum is not (1e308 + 1e308)
        samples.extend(finite)
    else:  # the parts are not needed (or one of them is missing): counted, not silently lost
        ignored += len(user_acc) + len(gravity)
    held = frozenset(s.kind for s in samples)  # the calibrated types (the parts' sum included)
    heard = held | frozenset(calibrated) | ({SensorKind.ACC} if have_total else set())
    for kind, timed in raw_readings.items():
        if kind in heard or (kind is SensorKind.ACC and user_acc and gravity and parts):
            ignored += len(timed)  # the calibrated type is the stream's: the raw one never beside it
            continue
        scale = 1.0
        if kind is SensorKind.ACC:
            norm = sorted(math.hypot(*xyz) for _, xyz in timed)[len(timed) // 2]
            scale = G if 0.5 < norm < 2.0 else 1.0  # iOS's raw accelerometer reads in g
        for t, (x, y, z) in timed:
            xyz = (x * scale, y * scale, z * scale)
            if all(math.isfinite(v) for v in xyz):
                samples.append(SensorSample(t, kind, xyz))
            else:
                bad += 1
    samples.sort(key=lambda s: (s.t_s, int(s.kind)))
    device, session = app_id(doc.get("deviceId")), app_id(doc.get("sessionId"))
    return PushBatch(samples, bad, ignored, message_id, have_total, device, session, held)


EPOCH_BANDS = (
    (10**15, 10**16, 1_000, 10**6),
    (10**12, 10**13, 10**6, 10**3),
    (10**9, 10**10, 10**9, 1),
)
"""A batch's ``time`` read in another unit than the app's ns: (lowest, highest) an epoch in that unit can
be (2001–2286: µs, ms, s), its ns per unit, and the spacing of one sensor's readings below which they are
in it (in ns, a sensor at 1 kHz is 1e6 apart; in µs, one at 1 Hz is; in ms, 1e3; in s, 1)."""


def time_unit(readings: Sequence[tuple[str, int | float, Any]]) -> int:
    """The ns per unit of a batch's ``time`` values: 1 (the app's ns), or that of µs, ms or s when the
    batch's median time is an epoch in that unit (:data:`EPOCH_BANDS`) and its sensors' readings are as
    far apart as a sensor's are in it (another client, a re-export; read as ns, a 10-second recording in
    µs was 10 ms long and dropped as a flood). With one reading per sensor only a µs epoch is told by its
    size: one in ms or s is also a ns clock 1–10 000 s from its start (the emulator's phone's)."""
    if not readings:
        return 1
    times = sorted(float(raw) for _, raw, _ in readings)
    median = abs(times[len(times) // 2])
    steps = []
    for name in {name for name, _, _ in readings}:
        own = sorted(float(raw) for n, raw, _ in readings if n == name)
        steps += [b - a for a, b in zip(own, own[1:], strict=False) if b > a]
    spacing = sorted(steps)[len(steps) // 2] if steps else None
    for low, high, ns_per_unit, apart in EPOCH_BANDS:
        if not low <= median < high:
            continue
        if spacing is not None:
            return ns_per_unit if spacing < apart else 1
        return ns_per_unit if ns_per_unit == 1_000 else 1  # one reading each: by its size alone (µs)
    return 1


def _seconds(raw: int | float, ns_per_unit: int) -> float:
    """A ``time`` value as seconds: int / int is correctly rounded, so t_s survives a round trip through
    integer nanoseconds."""
    if isinstance(raw, int):
        return raw * ns_per_unit / 1_000_000_000
    return raw * ns_per_unit * 1e-9


def _reading(entry: dict[str, Any]) -> tuple[int | float, tuple[float, float, float]] | None:
    """An entry's ``time`` (as written: an int, or a float) and its ``values``; None when unusable."""
    values, t_raw = entry.get("values"), entry.get("time")
    if not isinstance(values, dict) or isinstance(t_raw, bool) or not isinstance(t_raw, (int, float, str)):
        return None
    try:
        whole = isinstance(t_raw, int) or (isinstance(t_raw, str) and t_raw.isascii() and t_raw.isdigit())
        raw: int | float = int(t_raw) if whole else float(t_raw)
        seconds = float(raw) * 1e-9  # finite in any unit iff finite in ns
    except (TypeError, ValueError, OverflowError):  # OverflowError: a 400-digit integer
        return None
    x, y, z = (reading_number(values.get(axis)) for axis in "xyz")  # a bool is none (never true as 1.0)
    if x is None or y is None or z is None or not math.isfinite(seconds) or abs(raw) > 1e300:
        return None
    return raw, (x, y, z)


def _total_from_parts(user: list[_Timed], gravity: list[_Timed]) -> list[SensorSample]:
    """Specific force = user acceleration + gravity, pairing each user sample with the nearest-in-time
    gravity sample of the same batch (the app reports both from one fused source at one rate)."""
    if not user or not gravity:
        return []
    gravity.sort()
    out = []
    j = 0
    for t, (ux, uy, uz) in sorted(user):
        while j + 1 < len(gravity) and abs(gravity[j + 1][0] - t) <= abs(gravity[j][0] - t):
            j += 1
        gx, gy, gz = gravity[j][1]
        out.append(SensorSample(t, SensorKind.ACC, (ux + gx, uy + gy, uz + gz)))
    return out


def encode_push(samples: Iterable[SensorSample], message_id: int, session: str, device: str) -> bytes:
    """One HTTP Push batch in the app's schema (the inverse of :func:`decode_push` for our three sensors)."""
    payload = [
        {
            "name": _NAME_OF[s.kind],
            "time": round(s.t_s * 1e9),
            "values": {"x": s.xyz[0], "y": s.xyz[1], "z": s.xyz[2]},
        }
        for s in samples
    ]
    doc = {"messageId": message_id, "sessionId": session, "deviceId": device, "payload": payload}
    return json.dumps(doc, separators=(",", ":")).encode()


class PhonePushServer(PhoneReceiver):
    """Receives Sensor Logger pushes at ``http://HOST:PORT/PATH`` (port 0 picks a free one; see :attr:`url`).

    A background thread serves HTTP; :meth:`drain` hands the samples received so far to the consumer (the
    runtime's estimator task), at most ``max_batch`` a call (:mod:`.stream`). ``GET PATH`` answers 200 so
    the app's "Tap to Test Pushing" button succeeds; any other path is answered 404 and counted
    (``not_found``). A push's body is decoded in a process of its own (:mod:`.push_decoder`: no push can
    stall the host's control loop); one that cannot be read is answered 400 and counted, one the decoder
    could not take in time 503. Whatever a peer sends, a body is at most ``max_body`` bytes, a request has
    ``timeout_s`` to arrive, at most ``max_connections`` are served at once, idle ones making way for new
    ones (:mod:`.http_guard`), and only this server's socket failing is fatal: that error is stored and
    raised by :meth:`check` — threads never die silently. It follows one phone (the module docstring);
    ``clock`` (s, monotonic) times that phone's silence and paces the warnings.
    """

    scheme = "http"
    app = "Sensor Logger (HTTP Push)"

    def __init__(
        self,
        url: str = "http://127.0.0.1:8123/",
        max_queue: int = MAX_QUEUE,
        max_body: int = MAX_BODY,
        timeout_s: float = REQUEST_TIMEOUT_S,
        max_connections: int = MAX_CONNECTIONS,
        max_batch: int = MAX_BATCH,
        decode_timeout_s: float = DECODE_TIMEOUT_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        super().__init__(max_queue, clock, max_batch)
        host, port, self.path = _address(url)
        self._numbering = MessageNumbering()  # the followed stream's messageIds: its batches lost
        self._peer_numberings = PeerNumberings()  # who a batch without ids is, behind its address
        limits = HttpLimits(max_body, timeout_s, max_connections)
        try:
            self._httpd = GuardedHTTPServer((host, port), _handler(self), limits, self._turned_away)
        except OSError as exc:
            raise LinkError(f"cannot listen for phone pushes on {host}:{port}: {exc.strerror}") from exc
        self._decoder = PushDecoder(decode_timeout_s)  # its process starts at the first large push
        self._thread = threading.Thread(target=self._serve, name="phone-push", daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        host = self._httpd.server_address[0]
        host = host.decode() if isinstance(host, bytes) else host
        return f"http://{host}:{self._httpd.server_port}{self.path}"

    def _serve(self) -> None:
        with self._thread_error.caught():  # raised by check()
            self._httpd.serve_forever(poll_interval=0.05)

    def _accept(self, body: bytes, peer: str) -> tuple[int, str]:
        """One push's body into the queue — decoded here if small (:data:`INLINE_MAX`), else by the decoder
        process —: ``(status, text)`` to answer."""
        source = f"push from {peer}"
        # the calibrated types streaming (total acceleration: "total"), whose raw types are not read
        streaming = self._calibrated_streaming()
        parts = "total" not in streaming
        calibrated = frozenset(kind for kind in SensorKind if kind.label in streaming)
        batch, answer = self._decode_push(body, source, parts, calibrated)
        if batch is None:
            return answer
        usable = sum(batch.per_kind.values())
        decision = self._followed(batch.device, batch.session, batch.message_id, peer, usable)
        if decision is Decision.OTHER:
            return 200, OTHER_PHONE
        if decision is Decision.SWITCHED and (not parts or calibrated):  # read for the phone before: anew
            batch, answer = self._decode_push(body, source, True, frozenset())
            if batch is None:
                return answer
        if decision.streams:
            heard = [kind.label for kind in batch.calibrated]
            self._calibrated_heard([*heard, "total"] if batch.total else heard)
            self._count_gaps(batch.message_id)
        self._deliver(batch.samples, batch.bad, batch.ignored, batch.per_kind)
        return 200, "ok"

    def _decode_push(
        self, body: bytes, source: str, parts: bool, calibrated: frozenset[SensorKind]
    ) -> tuple[Decoded | None, tuple[int, str]]:
        """``(batch, _)``, or ``(None, (status, text))`` to answer a push that could not be read (counted)."""
        if len(body) <= INLINE_MAX:
            decode = partial(decode_push, parts=parts, calibrated=calibrated)
            inline, refused = self._decode(decode, body, source)
            if inline is None:
                return None, (400, refused)
            per_kind = dict(Counter(s.kind.label for s in inline.samples))
            return Decoded(
                inline.samples,
                inline.bad,
                inline.ignored,
                inline.message_id,
                per_kind,
                inline.total,
                inline.device,
                inline.session,
                inline.calibrated,
            ), (200, "ok")
        try:
            batch = self._decoder.decode(body, self._max_queue, source, parts, calibrated)
        except InputFormatError as exc:
            self._reject(str(exc))
            return None, (400, str(exc))
        except LinkError as exc:  # the decoder was busy, silent or dead: this push is lost, and counted
            with self._lock:
                self.stats.decoder_restarts = self._decoder.restarts
            self._reject(f"{source}: not decoded: {exc}")
            return None, (503, f"not decoded: {exc}")
        with self._lock:
            self.stats.decoder_restarts = self._decoder.restarts
        return batch, (200, "ok")

    def _followed(
        self, device: str | None, session: str | None, message_id: int | None, peer: str, usable: int
    ) -> Decision:
        """Whose a batch is (:mod:`.senders`); another phone's is counted there, never delivered. A batch
        without ids is its peer's address and the ``messageId`` numbering it continues
        (:class:`PeerNumberings`: two clients behind one address stay two). A new phone followed starts
        the stream's state afresh: its ``messageId`` numbering, and which calibrated types it sends (total
        acceleration among them)."""
        if device is None and session is None and message_id is None:
            sender: tuple[str | int | None, ...] = ("peer", peer)
            name = f"{peer} (no deviceId, sessionId or messageId)"
        elif device is None and session is None:
            with self._lock:
                number = self._peer_numberings.which(peer, message_id)  # type: ignore[arg-type]
            sender = ("peer", peer, number)
            name = f"{peer} (no deviceId or sessionId; messageId numbering #{number})"
        else:
            sender = ("app", device, session)
            name = f"deviceId {device!r} sessionId {session!r} from {peer}"
        decision = self._attribute(sender, name, usable)
        if decision is Decision.SWITCHED:
            with self._lock:
                self._numbering = MessageNumbering()
            self._calibrated_forget()
        return decision

    def _count_gaps(self, message_id: int | None) -> None:
        """Batches lost in transit, by the followed stream's ``messageId`` (:class:`MessageNumbering`): a
        late one uncounted again, a retry nothing, a jump back or too far a numbering started again
        (``message_restarts``; counted, not logged: an app restarts), never a count of losses no phone
        could have sent."""
        if message_id is None:
            return
        with self._lock:
            lost, restarts = self._numbering.hear(message_id)
            self.stats.message_gaps += lost
            self.stats.message_restarts += restarts

    def _turned_away(self, reason: str, peer: str, detail: str) -> None:
        """What the HTTP guard (and the handler) turned away: counted by kind; requests also logged."""
        with self._lock:
            st = self.stats
            if reason == "connections":
                st.refused_connections += 1
            elif reason == "evicted":
                st.evicted_connections += 1
            elif reason == "timeout":
                st.timeouts += 1
            elif reason == "path":
                st.not_found += 1
        if reason == "path":
            self._warn(f"a request from {peer} for {detail}: not the push path {self.path}")
        elif reason not in ("connections", "evicted", "timeout"):
            self._reject(f"push from {peer}: {detail}")

    def close(self) -> None:
        """Stop serving, drop open (keep-alive) connections, stop the decoder and release the port.
        Idempotent."""
        if self._thread.is_alive():
            self._httpd.shutdown()
            self._thread.join(timeout=5.0)
        self._httpd.server_close()
        self._httpd.close_connections()
        self._decoder.close()


def _handler(server: PhonePushServer) -> type[GuardedHandler]:
    """The request handler class of ``server``: keep-alive HTTP/1.1 under the guard (:mod:`.http_guard`);
    only ``server.path`` is served."""

    class Handler(GuardedHandler):
        protocol_version = "HTTP/1.1"
        # The answer goes out as two writes (headers, body): with Nagle's algorithm the second waits for
        # the peer's delayed ACK of the first, 40 ms a batch on Linux, and the app waits for the answer.
        disable_nagle_algorithm = True

        def _ours(self) -> bool:
            """Whether the request is for the push path; if not, answered 404 and counted."""
            path = urlsplit(self.path).path
            if path == server.path:
                return True
            server._turned_away("path", self.client_address[0], f"{self.command} {path[:80]!r}")
            self.close_connection = True  # its body, if any, is not read
            self._answer(404, f"no such path: the push path is {server.path}")
            return False

        def do_POST(self) -> None:  # noqa: N802 (http.server's naming)
            if not self._ours():
                return
            peer = self.client_address[0]
            try:
                body = self.read_body(f"push from {peer}")
            except BodyError as exc:
                if self.server.was_evicted(self.connection):
                    return  # its slot went to a new connection: counted as evicted
                server._reject(str(exc))
                self.close_connection = True  # the rest of what this peer sent cannot be trusted
                self._answer(exc.status, exc.detail)
                return
            code, text = server._accept(body, peer)
            self._answer(code, text)

        def do_GET(self) -> None:  # noqa: N802
            if self._ours():
                self._answer(200, "vscmg-hil phone push receiver")

        def _answer(self, code: int, text: str) -> None:
            data = text.encode()
            self.deadline_for_answer()  # a peer that does not read its answer cannot hold us
            try:
                self.send_response(code)
                self.send_header("Content-Type", "text/plain")
                self.send_header("Content-Length", str(len(data)))
                if self.close_connection:
                    self.send_header("Connection", "close")
                self.end_headers()
                self.wfile.write(data)
            except OSError:  # the peer went away or stopped reading: its push still counts
                self.close_connection = True

    return Handler


class PhonePushSender:
    """Sends batches to a push URL as the app does (keep-alive HTTP/1.1 POSTs with JSON bodies).

    A refused or failed POST is counted and the connection reopened on the next batch: a phone app
    keeps streaming while the host restarts.
    """

    batch_s = 0.02  # s: the app's shortest batch period worth using

    def __init__(
        self,
        url: str,
        session: str = "vscmg-hil-sim",
        device: str = "simulated-phone",
        timeout_s: float = 2.0,
    ) -> None:
        self.url = url
        self._host, self._port, self._path = _address(url)
        self._timeout = timeout_s
        self._conn: http.client.HTTPConnection | None = None
        self.session, self.device = session, device
        self.message_id = 0
        self.sent = 0
        self.failed = 0

    def send(self, samples: Sequence[SensorSample]) -> bool:
        """POST one batch; True if the receiver answered 200."""
        body = encode_push(samples, self.message_id, self.session, self.device)
        self.message_id += 1
        for attempt in (0, 1):  # one reconnect: a keep-alive connection may have been closed meanwhile
            try:
                if self._conn is None:
                    self._conn = http.client.HTTPConnection(self._host, self._port, timeout=self._timeout)
                self._conn.request("POST", self._path, body, {"Content-Type": "application/json"})
                response = self._conn.getresponse()
                response.read()
                if response.status == 200:
                    self.sent += 1
                    return True
                self.failed += 1
                return False
            except (OSError, http.client.HTTPException):
                self.close()
                if attempt:
                    self.failed += 1
                    return False
                time.sleep(0.01)
        return False

    def close(self) -> None:
        if self._conn is not None:
            self._conn.close()
            self._conn = None
