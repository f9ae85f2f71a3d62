"""Sensor Logger pushes decoded in a process of their own, so that no push can stall the host's control loop.

Why a process: a push may be 4 MiB of JSON (``MAX_BODY``), 50 000 readings. ``json.loads`` of that holds
the interpreter's lock for ~0.1 s, and turning it into samples is ~0.3 s of Python besides; in the host's
process both compete with the control thread, which then starts late (issue 26: 0.3-0.7 s late, board
failsafes, with the host handed only bounded batches). In a child process they cost the control loop
nothing but a CPU core's share: the server's handler thread writes the body to a pipe and waits for the
answer with the lock released, and the answer holds only what the host's queue can keep. (The server
decodes a push the size the app sends — a few kB — in its own thread: :data:`~.phone_push.INLINE_MAX`.)

The child is started at the first push that needs it (its imports take ~0.3-1 s; a server that only ever
sees small pushes never starts one) and kept for the next.

:class:`PushDecoder` is the host's end; ``python -m hil.link.sources.push_decoder`` (:func:`main`) the
child, which runs :func:`~hil.link.sources.phone_push.decode_push` — the same pure function the tests
call — on each body. The pipe protocol, little-endian, one exchange at a time:

=========  =============================  ===============================================================
direction  bytes                          what
=========  =============================  ===============================================================
request    u32 ``size``, u32 ``keep``,    then ``size`` bytes of the push's body (``flags``: bit 0
           u8 ``flags``                   ``parts``, bit 1 + kind: ``calibrated``, of decode_push)
reply      u32 ``n``                      then ``n`` bytes: u32 ``h``, ``h`` bytes of a JSON header, and
                                          33-byte records ``<dBddd`` (``t_s``, sensor kind, x, y, z)
=========  =============================  ===============================================================

The header is ``{"error": detail}`` for a body that is not a push, else ``{"bad", "ignored",
"message_id", "per_kind", "records", "total", "device", "session", "calibrated"}``: the counts are
the whole push's (its ids, shortened: :func:`~hil.link.sources.phone_push.app_id`); the records are its
newest ``keep`` samples
in time order (what the host's queue would keep: the older ones would be dropped on
arrival anyway, and are counted there without being built).

A child that does not answer within ``timeout_s`` is killed; one that died is started afresh for the
next push (``restarts``). Either costs that one push (a :class:`~protocol.errors.LinkError`, which the
server answers 503 and counts), never the server. The child runs at a lower priority (:data:`NICE`: on a busy
machine the control loop, and an emulated board beside it, get the CPU first; a push waits), ignores
SIGINT and runs in its own session (a Ctrl-C to ``hil run`` is the host's to handle), prints nothing, and
exits when its input closes — also when the host is killed.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import struct
import subprocess
import sys
import tempfile
import threading
from dataclasses import dataclass, field
from typing import IO, Any

from hil.estimation.sensors import KINDS, SensorKind, SensorSample
from protocol.errors import InputFormatError, LinkError, LinkTimeout

DECODE_TIMEOUT_S = 5.0
"""s: how long a push may wait for the decoder and then for its answer (a 4 MiB push takes ~0.3 s)."""
NICE = 10
"""The decoder's niceness above the host's: bulk work, behind the control loop for the CPU."""
_REQUEST = struct.Struct("<IIB")  # body size, samples to keep, flags: bit 0 the parts may make the
# accelerometer, bit 1 + kind the stream has sent that sensor's calibrated type (decode_push's calibrated)
_LENGTH = struct.Struct("<I")
_RECORD = struct.Struct("<dBddd")
_MAX_REPLY = 64 * 1024 * 1024  # bytes: a reply claiming more is a broken child, not a push


@dataclass
class Decoded:
    """One push, decoded: its newest samples (at most ``keep``, time order) and the whole push's counts."""

    samples: list[SensorSample]
    bad: int
    ignored: int
    message_id: int | None
    per_kind: dict[str, int] = field(default_factory=dict)
    total: bool = False  # the push held total acceleration (PushBatch.total)
    device: str | None = None  # its deviceId and sessionId (PushBatch.device, .session)
    session: str | None = None
    calibrated: frozenset[SensorKind] = frozenset()  # PushBatch.calibrated


class PushDecoder:
    """The host's end of the decoder process, started at the first :meth:`decode`. :meth:`decode` is safe
    to call from several threads (one push at a time goes through the pipe; the others wait, at most
    ``timeout_s``). :meth:`close` is idempotent."""

    def __init__(self, timeout_s: float = DECODE_TIMEOUT_S) -> None:
        self.timeout_s = timeout_s
        self.restarts = 0  # children started after the first (one died or was killed)
        self._lock = threading.Lock()
        self._proc: subprocess.Popen[bytes] | None = None
        self._stderr: IO[bytes] | None = None
        self._closed = False

    def _start(self) -> subprocess.Popen[bytes]:
        if self._stderr is not None:
            self._stderr.close()
        self._stderr = tempfile.TemporaryFile()  # read only to say why a child died
        try:
            proc = subprocess.Popen(
                [sys.executable, "-m", __name__],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=self._stderr,
                start_new_session=True,
            )
        except OSError as exc:
            raise LinkError(f"cannot start the push decoder: {exc.strerror or exc}") from exc
        self._proc = proc
        return proc

    def _running(self) -> subprocess.Popen[bytes]:
        proc = self._proc
        if proc is not None and proc.poll() is None:
            return proc
        if proc is not None:
            self._stop(proc)
            self.restarts += 1
        return self._start()

    def decode(
        self,
        body: bytes,
        keep: int,
        source: str,
        parts: bool = True,
        calibrated: frozenset[SensorKind] = frozenset(),
    ) -> Decoded:
        """``body`` decoded by the child (:func:`~hil.link.sources.phone_push.decode_push` with ``parts``
        and ``calibrated``):
        its newest ``keep`` samples and its counts. Raises
        :class:`InputFormatError` (naming ``source``) for a body that is not a push, :class:`LinkTimeout`
        when the decoder is busy or silent for ``timeout_s``, :class:`LinkError` when it died."""
        if not self._lock.acquire(timeout=self.timeout_s):
            raise LinkTimeout(f"the push decoder stayed busy for {self.timeout_s} s")
        try:
            if self._closed:
                raise LinkError("the push decoder is closed")
            flags = int(parts) | sum(2 << int(kind) for kind in calibrated)
            reply = self._exchange(self._running(), body, max(keep, 1), flags)
        finally:
            self._lock.release()
        return _unpack(reply, source)

    def _exchange(self, proc: subprocess.Popen[bytes], body: bytes, keep: int, flags: int) -> bytes:
        assert proc.stdin is not None and proc.stdout is not None
        killer = threading.Timer(self.timeout_s, proc.kill)  # a silent child is killed: the pipe then ends
        killer.daemon = True
        killer.start()
        try:
            proc.stdin.write(_REQUEST.pack(len(body), keep, flags))
            proc.stdin.write(body)
            proc.stdin.flush()
            (n,) = _LENGTH.unpack(_exact(proc.stdout, _LENGTH.size))
            if n > _MAX_REPLY:
                raise EOFError(f"a reply of {n} bytes")
            return _exact(proc.stdout, n)
        except (OSError, ValueError, EOFError) as exc:  # ValueError: a pipe closed under us
            fired = killer.finished.is_set()
            self._stop(proc)
            if fired:
                raise LinkTimeout(f"the push decoder did not answer within {self.timeout_s} s") from exc
            raise LinkError(f"the push decoder died ({self._why()})") from exc
        finally:
            killer.cancel()

    def _why(self) -> str:
        proc, err = self._proc, self._stderr
        status = "running" if proc is None or proc.returncode is None else f"exit status {proc.returncode}"
        if err is None:
            return status
        with contextlib.suppress(OSError, ValueError):
            err.seek(0)
            last = err.read()[-300:].decode("utf-8", "replace").strip().splitlines()
            return f"{status}: {last[-1]}" if last else status
        return status

    def _stop(self, proc: subprocess.Popen[bytes] | None) -> None:
        if proc is None:
            return
        for pipe in (proc.stdin, proc.stdout):
            with contextlib.suppress(OSError, ValueError):
                if pipe is not None:
                    pipe.close()
        try:
            proc.wait(timeout=2.0)  # its input closed: it exits
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()

    def close(self) -> None:
        """Stop the child (its input closed; killed if it does not exit within 2 s). Idempotent."""
        with self._lock:
            self._closed = True
            self._stop(self._proc)
            if self._stderr is not None:
                self._stderr.close()
                self._stderr = None


def _exact(stream: IO[bytes], n: int) -> bytes:
    data = stream.read(n)
    if len(data) != n:
        raise EOFError(f"the decoder's answer ended after {len(data)} of {n} bytes")
    return data


def _unpack(reply: bytes, source: str) -> Decoded:
    """A reply of the child as :class:`Decoded`, or :class:`InputFormatError` when it refused the body. A
    reply that does not parse is the child's fault: :class:`LinkError`."""
    try:
        (h,) = _LENGTH.unpack_from(reply)
        header: dict[str, Any] = json.loads(reply[_LENGTH.size : _LENGTH.size + h])
        if "error" in header:
            raise InputFormatError(str(header["error"]), source)
        records = reply[_LENGTH.size + h :]
        if len(records) != header["records"] * _RECORD.size:
            raise ValueError(f"{len(records)} bytes of records, {header['records']} announced")
        samples = [SensorSample(t, KINDS[k], (x, y, z)) for t, k, x, y, z in _RECORD.iter_unpack(records)]
        total, device, session = header["total"], header["device"], header["session"]
        if not isinstance(total, bool):
            raise TypeError(f"total is {total!r}")
        if not all(v is None or isinstance(v, str) for v in (device, session)):
            raise TypeError(f"the ids are {device!r}, {session!r}")
        calibrated = frozenset(KINDS[k] for k in header["calibrated"])
        return Decoded(
            samples,
            header["bad"],
            header["ignored"],
            header["message_id"],
            header["per_kind"],
            total,
            device,
            session,
            calibrated,
        )
    except InputFormatError:
        raise
    except (ValueError, KeyError, TypeError, IndexError, struct.error) as exc:
        raise LinkError(f"the push decoder's answer is malformed: {exc}") from exc


# ------------------------------------------------------------------------------------------- the child
def answer(
    body: bytes, keep: int, parts: bool = True, calibrated: frozenset[SensorKind] = frozenset()
) -> bytes:
    """The reply (without its length prefix) to one request: what the child sends for ``body``."""
    from hil.link.sources.phone_push import decode_push

    records = b""
    try:
        batch = decode_push(body, parts=parts, calibrated=calibrated)
    except InputFormatError as exc:
        header: dict[str, Any] = {"error": exc.detail}
    except Exception as exc:  # whatever hostile input makes a parser raise costs this push only
        header = {"error": f"unreadable ({type(exc).__name__}: {str(exc)[:120]})"}
    else:
        samples = batch.samples
        per_kind: dict[str, int] = {}
        for s in samples:
            per_kind[s.kind.label] = per_kind.get(s.kind.label, 0) + 1
        kept = samples[len(samples) - min(keep, len(samples)) :]
        records = b"".join(_RECORD.pack(s.t_s, int(s.kind), *s.xyz) for s in kept)
        header = {
            "bad": batch.bad,
            "ignored": batch.ignored,
            "message_id": batch.message_id,
            "per_kind": per_kind,
            "records": len(kept),
            "total": batch.total,
            "device": batch.device,
            "session": batch.session,
            "calibrated": sorted(int(kind) for kind in batch.calibrated),
        }
    text = json.dumps(header).encode()
    return _LENGTH.pack(len(text)) + text + records


def main() -> int:
    """Answer requests on stdin until it closes."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the host handles Ctrl-C; this ends when its input does
    with contextlib.suppress(OSError):
        os.nice(NICE)
    stdin, stdout = sys.stdin.buffer, sys.stdout.buffer
    while True:
        head = stdin.read(_REQUEST.size)
        if len(head) < _REQUEST.size:
            return 0
        size, keep, flags = _REQUEST.unpack(head)
        body = stdin.read(size)
        if len(body) < size:
            return 0
        calibrated = frozenset(kind for kind in KINDS if flags & (2 << int(kind)))
        reply = answer(body, keep, bool(flags & 1), calibrated)
        stdout.write(_LENGTH.pack(len(reply)) + reply)
        stdout.flush()


if __name__ == "__main__":
    sys.exit(main())
