"""The transport interface: a byte pipe to the board, opened from a URL.

Template method (after python-can's ``BusABC``): the public ``read``/``write``/``close`` own the
bookkeeping (open state, byte counters, error translation) once; each backend writes only
``_open``, ``_read(timeout)``, ``_write(data)`` and ``_close``. Every backend error surfaces as a
:class:`protocol.errors.LinkError` (``LinkTimeout`` for deadlines), never as a backend-specific one.
"""

from __future__ import annotations

import abc
import threading
from types import TracebackType
from urllib.parse import parse_qs, urlsplit

from protocol.errors import ConfigError, LinkError, TransportError, TransportRefused


class Transport(abc.ABC):
    """A byte stream to the board. ``close()`` is idempotent; use as a context manager."""

    scheme: str = ""

    def __init__(self, url: str) -> None:
        self.url = url
        self.bytes_in = 0
        self.bytes_out = 0
        self._open = False
        self._lock = threading.Lock()
        self._failure_after_data: LinkError | None = None  # raised by the next read (_hand_up_then_fail)

    # ------------------------------------------------------------------ public
    @property
    def is_open(self) -> bool:
        return self._open

    def present(self) -> bool | None:
        """Whether the port's device is there now, where that is cheap to tell (a device path on disk,
        looked at without opening it); None where it cannot be told. A client whose link is down tries
        again at once when an absent port appears (a board restarted, a cable plugged back in), rather
        than at its back-off's next step."""
        return None

    def heard_instead(self) -> str:
        """What this transport received that the board's answer never is, said for the operator ("; ..." or
        empty): a first handshake that timed out appends it to its ``LinkTimeout``."""
        return ""

    def open(self) -> Transport:
        if not self._open:
            try:
                self._open_impl()
            except LinkError:
                raise
            except ConfigError as exc:  # the options describe no board: no second try will open it
                raise TransportRefused(f"{self.url}: cannot open: {exc}") from exc
            except (OSError, ValueError) as exc:
                raise TransportError(f"{self.url}: cannot open: {exc}") from exc
            self._open = True
        return self

    def read(self, timeout: float | None = 0.05) -> bytes:
        """Bytes available now, waiting up to ``timeout`` s for the first one (``b""`` if none arrive).

        Raises LinkError if the port vanished (far side closed, device unplugged)."""
        if not self._open:
            raise LinkError(f"{self.url}: read on a closed transport")
        failure, self._failure_after_data = self._failure_after_data, None
        if failure is not None:
            raise failure
        try:
            data = self._read(timeout)
        except LinkError:
            raise
        except Exception as exc:
            if self._open:  # a fault of its own, as it is
                raise
            raise self._closed_under(exc, "read") from exc
        self.bytes_in += len(data)
        return data

    def write(self, data: bytes) -> None:
        if not self._open:
            raise LinkError(f"{self.url}: write on a closed transport")
        with self._lock:  # writers on several threads must not interleave frames
            try:
                self._write(data)
            except LinkError:
                raise
            except Exception as exc:
                if self._open:
                    raise
                raise self._closed_under(exc, "write") from exc
        self.bytes_out += len(data)

    def _closed_under(self, exc: Exception, what: str) -> LinkError:
        """A backend's error after the transport was closed by another thread under the ``what`` (a
        reconnect's close while the reader thread reads: pyserial then fails on its released descriptor
        with a TypeError, a backend's check that its port is there fails): a :class:`LinkError`, as a
        vanished port is. While the transport is open, an unexpected error is raised as it is."""
        return LinkError(f"{self.url}: the transport was closed during a {what} ({exc!r})")

    def _hand_up_then_fail(self, data: bytes | bytearray, failure: LinkError) -> bytes:
        """For a backend's ``_read`` whose port failed after it took ``data`` in that same read: the bytes
        are handed up now and ``failure`` is raised by the next read (at once, when nothing was taken). A
        far side's last bytes come just before its end — a board's last frame before it reset, its final
        0x00 alone in a socket's last segment — and raised at once, they were lost with the read."""
        if not data:
            raise failure
        self._failure_after_data = failure
        return bytes(data)

    def close(self) -> None:
        self._failure_after_data = None  # a reopened port starts afresh
        if self._open:
            self._open = False
            self._close()

    def __enter__(self) -> Transport:
        return self.open()

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.url} {'open' if self._open else 'closed'}>"

    # ------------------------------------------------------------------ backend
    @abc.abstractmethod
    def _open_impl(self) -> None: ...

    @abc.abstractmethod
    def _read(self, timeout: float | None) -> bytes: ...

    @abc.abstractmethod
    def _write(self, data: bytes) -> None: ...

    @abc.abstractmethod
    def _close(self) -> None: ...


class UrlOptions:
    """Query-string options of a transport URL; every option must be consumed, unknown ones raise
    (like pyserial's URL handlers), so a typo never passes silently."""

    def __init__(self, url: str) -> None:
        self.url = url
        parts = urlsplit(url)
        self.scheme = parts.scheme
        self.netloc = parts.netloc
        self.path = parts.path
        self._values: dict[str, str] = {}
        for key, values in parse_qs(parts.query, keep_blank_values=True).items():
            if len(values) != 1:
                raise TransportError(f"{url}: option {key!r} given {len(values)} times")
            self._values[key] = values[0]
        self._used: set[str] = set()

    def get(self, key: str, default: str | None = None) -> str | None:
        self._used.add(key)
        return self._values.get(key, default)

    def get_float(self, key: str, default: float) -> float:
        raw = self.get(key)
        if raw is None:
            return default
        try:
            return float(raw)
        except ValueError:
            raise TransportError(f"{self.url}: option {key}={raw!r} is not a number") from None

    def get_int(self, key: str, default: int) -> int:
        raw = self.get(key)
        if raw is None:
            return default
        try:
            return int(raw, 0)
        except ValueError:
            raise TransportError(f"{self.url}: option {key}={raw!r} is not an integer") from None

    def get_bool(self, key: str, default: bool) -> bool:
        raw = self.get(key)
        if raw is None:
            return default
        if raw.lower() in ("1", "true", "yes", "on", ""):
            return True
        if raw.lower() in ("0", "false", "no", "off"):
            return False
        raise TransportError(f"{self.url}: option {key}={raw!r} is not a boolean")

    def finish(self) -> None:
        """Raise for options nobody asked for."""
        unknown = sorted(set(self._values) - self._used)
        if unknown:
            raise TransportError(f"{self.url}: unknown option(s) {', '.join(unknown)}")
