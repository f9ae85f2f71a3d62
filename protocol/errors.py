"""The project's one exception tree.

It lives in the lowest layer (``protocol``) so that ``hil`` and ``firmware_sim``, which both import
``protocol``, raise and catch the same classes.  Every class also inherits the built-in exception it
resembles (``ValueError``, ``ConnectionError``, ``TimeoutError`` ...), so generic ``except`` clauses keep
working.  Errors say *where*: a field of a frame, a key of a config file, a file/line/column of a log.
"""

from __future__ import annotations

import math
import reprlib

_MAX_REPR = 80
"""Characters of a caller's value an error message shows at most."""


class _BoundedRepr(reprlib.Repr):
    """``reprlib``'s length limits, and an integer too long to spell shown by its size: ``repr`` of an int
    past 4300 digits raises ``ValueError`` (CPython's guard against quadratic conversion), and reprlib
    calls it before it shortens anything."""

    def __init__(self) -> None:
        super().__init__()
        self.maxstring = self.maxother = _MAX_REPR

    def repr_int(self, x: int, level: int) -> str:
        bits = abs(x).bit_length()
        if bits <= 128:  # up to 39 digits: spelled out
            return repr(x)
        digits = int(bits * math.log10(2)) + 1  # exact or one too many: the size is what matters
        return f"<a{' negative' if x < 0 else 'n'} integer of ~{digits} digits>"


_BOUNDED_REPR = _BoundedRepr()


def value_repr(value: object) -> str:
    """``repr(value)`` for an error message, at most ~80 characters whatever the caller passed: a 10**5000
    in a field made building the error raise Python's own ``ValueError`` ("Exceeds the limit (4300 digits)
    for integer string conversion") in place of the typed error, and a megabyte string made a megabyte
    message. The one way to show a caller's value in an error this project raises."""
    text = _BOUNDED_REPR.repr(value)
    if len(text) > _MAX_REPR:  # a container of long items: reprlib bounds each item and their count only
        half = (_MAX_REPR - 3) // 2
        text = f"{text[:half]}...{text[-half:]}"
    return text


class HilError(Exception):
    """Root of every error this project raises on purpose."""


# --------------------------------------------------------------------------- protocol
class ProtocolError(HilError, ValueError):
    """A message or frame that cannot be encoded or decoded."""


class FieldRangeError(ProtocolError):
    """A message field outside its documented range (raised on encode)."""

    def __init__(self, message: str, field: str, value: object) -> None:
        super().__init__(f"{message}.{field} = {value_repr(value)} is out of range")
        self.message_name = message
        self.field = field
        self.value = value


class FrameError(ProtocolError):
    """A frame that fails to decode; ``reason`` is one of :class:`protocol.frame.BadFrameReason`."""

    def __init__(self, reason: object, detail: str = "") -> None:
        super().__init__(f"{reason}: {detail}" if detail else str(reason))
        self.reason = reason
        self.detail = detail


class CommandFailed(ProtocolError):
    """A reliable command was NACKed or never acknowledged after all retries."""


# --------------------------------------------------------------------------- configuration / data
class ConfigError(HilError, ValueError):
    """A bad configuration, scenario or parameter set; ``where`` names the file and key."""

    def __init__(self, detail: str, where: str = "") -> None:
        super().__init__(f"{where}: {detail}" if where else detail)
        self.where = where
        self.detail = detail


class CalibrationError(ConfigError):
    """A calibration table or bench CSV that is malformed, non-monotone or does not cover its range."""


class InputFormatError(HilError, ValueError):
    """A malformed input file (sensor log, CSV); says file, line and column."""

    def __init__(self, detail: str, path: str = "", line: int | None = None, column: str | None = None):
        where = path
        if line is not None:
            where += f":{line}"
        if column is not None:
            where += f" (column {column})"
        super().__init__(f"{where}: {detail}" if where else detail)
        self.path = path
        self.line = line
        self.column = column
        self.detail = detail


# --------------------------------------------------------------------------- numerics
class NumericalError(HilError, ArithmeticError):
    """A numerical method that failed (e.g. Newton-Raphson did not converge)."""


class ConvergenceError(NumericalError):
    """An iterative solver hit its iteration cap without meeting its tolerance."""


# --------------------------------------------------------------------------- link / runtime
class LinkError(HilError, ConnectionError):
    """The transport to the board failed, vanished or could not be opened."""


class LinkTimeout(LinkError, TimeoutError):
    """No answer from the far side within the deadline."""


class HandshakeError(LinkError):
    """The board answered the handshake with an incompatible version or schema hash."""


class BoardReset(LinkError):
    """The board reset under us; ``cause`` is the reset cause it reported."""

    def __init__(self, cause: object, detail: str = "") -> None:
        super().__init__(f"board reset (cause: {cause}){': ' + detail if detail else ''}")
        self.cause = cause


class TransportError(LinkError):
    """A transport URL that cannot be resolved or opened."""


class TransportRefused(TransportError):
    """A transport that opening again cannot open: its URL describes no board (an option's value the board
    refuses), or another host holds its port. A run fails on it at once rather than trying again for its
    outage bound."""


class PortBusy(TransportRefused):
    """A serial port that another process holds exclusively: another host is talking to that board.

    Every host locks its port (``flock``), so a second host cannot handshake with a board under the first
    one (the handshake would disarm it). ``holder_pid`` and ``holder_cmdline`` name the process that holds
    it, when it can be found (else None): that is what the user has to stop."""

    def __init__(self, port: str, holder_pid: int | None = None, holder_cmdline: str | None = None) -> None:
        if holder_pid is None:
            holder = "another process"
        else:
            holder = f"pid {holder_pid}" + (f" ({holder_cmdline})" if holder_cmdline else "")
        super().__init__(f"{port}: port busy: held by {holder} (another host is using this board)")
        self.port = port
        self.holder_pid = holder_pid
        self.holder_cmdline = holder_cmdline


class RunHung(HilError):
    """A run that did not end within its wall-clock budget (a campaign's guard against a loop that stops
    advancing simulated time): the campaign records it as a hang and goes on. Raised into the run's thread
    wherever it is, so deliberately no ``OSError`` (it was a ``TimeoutError``): an ``except OSError`` on
    the way — importlib's own, a file or socket read's — took it for an I/O error and went on."""
