"""MATLAB ``.mat`` files (BROAD trials, Qualisys exports) read bounded by what they are.

A level-5 MAT file is a 128-byte header and a sequence of data elements, each an 8-byte tag (type, byte
count) and its bytes; an element of type ``miCOMPRESSED`` is a zlib stream holding another element. SciPy
reads a compressed element by inflating it as it goes, to the sizes the inner element claims — so a small
file can claim, and inflate to, gigabytes. Before SciPy sees a file, :func:`check_expansion` walks its
top-level elements and inflates each compressed one in pieces, counting and dropping the bytes, and refuses
a file whose elements expand to more than :data:`MAX_MAT_EXPANDED` bytes together (or more than
:data:`~hil.files.bounded.MAX_COMPRESSION_RATIO` times their compressed size): what SciPy then builds is no
larger than what the file really holds. The file itself is at most :data:`~hil.logs.table.MAX_RAW_BYTES`.
"""

from __future__ import annotations

import io
import struct
import zlib
from typing import Any

import numpy as np
import scipy.io
from numpy.typing import NDArray

from hil.files.bounded import CHUNK_BYTES, MAX_COMPRESSION_RATIO, RATIO_GRACE_BYTES
from hil.logs.table import Container
from protocol.errors import InputFormatError

MAX_MAT_EXPANDED = 64 << 20
"""The most a MAT file's elements may hold together, inflated (64 MiB: a BROAD trial holds about 10 MB, a
Qualisys export less)."""
_HEADER_BYTES = 128
_MI_COMPRESSED = 15


def check_expansion(data: bytes, where: str) -> None:
    """Raise :class:`InputFormatError` naming ``where`` if the level-5 MAT file ``data`` inflates to more
    than :data:`MAX_MAT_EXPANDED` bytes (see the module docstring). Files of other levels (v4: nothing
    compressed; v7.3: HDF5, which :func:`load_mat` refuses by name) are left to SciPy."""
    if len(data) < _HEADER_BYTES or data[126:128] not in (b"IM", b"MI"):
        return
    order = "<" if data[126:128] == b"IM" else ">"
    position, expanded = _HEADER_BYTES, 0
    while position + 8 <= len(data):
        kind, size = struct.unpack_from(order + "II", data, position)
        position += 8
        if kind >> 16:  # a small element: its data is in the tag
            continue
        if kind == _MI_COMPRESSED:
            packed = data[position : position + size]
            expanded += _inflated_size(packed, MAX_MAT_EXPANDED - expanded, where)
            position += size
        else:
            expanded += size
            position += size + (-size % 8)  # padded to 8 bytes
        if expanded > MAX_MAT_EXPANDED:
            raise InputFormatError(f"its elements hold more than {MAX_MAT_EXPANDED} bytes", where)


def _inflated_size(packed: bytes, room: int, where: str) -> int:
    """Bytes the zlib stream ``packed`` inflates to, counted in pieces (never held), at most ``room``."""
    inflater = zlib.decompressobj()
    total = 0
    pending = packed
    while pending:
        try:
            total += len(inflater.decompress(pending, CHUNK_BYTES))
        except zlib.error as exc:
            raise InputFormatError(f"a damaged compressed element ({exc})", where) from None
        pending = inflater.unconsumed_tail
        if total > room:
            raise InputFormatError(f"its elements inflate to more than {MAX_MAT_EXPANDED} bytes", where)
        if total > RATIO_GRACE_BYTES and total > MAX_COMPRESSION_RATIO * len(packed):
            raise InputFormatError(
                f"a compressed element of {len(packed)} bytes inflates to more than {total} "
                f"(over {MAX_COMPRESSION_RATIO}:1): a compression bomb, not a recording",
                where,
            )
    return total


_V73_VERSION = (b"\x00\x02", b"\x02\x00")
"""The header's version field (bytes 124-126, little- or big-endian 0x0200) of a MATLAB v7.3 file."""
_HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


def is_v73(data: bytes) -> bool:
    """Whether ``data`` is a MATLAB v7.3 file: HDF5 behind a 512-byte MAT header (``save -v7.3``, the only
    format MATLAB writes for variables over 2 GB, and the default of some installations)."""
    if len(data) >= _HEADER_BYTES and data[124:126] in _V73_VERSION and data[126:128] in (b"IM", b"MI"):
        return True
    return data[512:520] == _HDF5_SIGNATURE or data[:8] == _HDF5_SIGNATURE


def load_mat(c: Container, name: str, **options: Any) -> dict[str, Any]:
    """``scipy.io.loadmat`` of a member, once :func:`check_expansion` has passed; any failure of SciPy's
    parser (whose errors on hostile bytes are of many types) is an :class:`InputFormatError` naming it.
    A v7.3 (HDF5) file is refused by name, with what to do: SciPy reads levels 4 and 5 only."""
    where = c.where(name)
    data = c.raw(name)
    if is_v73(data):
        raise InputFormatError(
            "a MATLAB v7.3 (HDF5) file, which is not read: save it again as v7 (MATLAB's "
            "save(..., '-v7')) or with scipy.io.savemat",
            where,
        )
    check_expansion(data, where)
    try:
        return scipy.io.loadmat(io.BytesIO(data), **options)  # type: ignore[no-any-return]
    except Exception as exc:  # noqa: BLE001 — a third-party parser on untrusted bytes
        raise InputFormatError(f"not a readable MATLAB file ({type(exc).__name__}: {exc})", where) from None


def mat_variables(c: Container, name: str) -> list[tuple[str, tuple[int, ...], str]]:
    """``scipy.io.whosmat`` of a member (name, shape, class of each variable), bounded as :func:`load_mat`;
    an unreadable file has none."""
    try:
        data = c.raw(name)
        check_expansion(data, c.where(name))
        return list(scipy.io.whosmat(io.BytesIO(data)))
    except InputFormatError:
        return []
    except Exception:  # noqa: BLE001 — detection: a file SciPy cannot list is not this format
        return []


RATE_HZ = (1.0, 10_000.0)
"""The sample and frame rates a ``.mat`` file may state (Hz): BROAD's IMU samples at 285.714, Qualisys
records at 60; an IMU or a motion-capture system runs at tens of Hz to a few kHz. A rate outside — 0, inf,
NaN, 1e300 — would put every sample at one instant (or at NaN, or days apart) and leave nothing
evaluated, silently."""
_REAL = "biuf"
"""NumPy dtype kinds that are real numbers: booleans, integers, floats (not text, objects or complex)."""


def real_array(value: Any, key: str, where: str) -> NDArray[np.float64]:
    """A ``.mat`` variable as an array of floats, or :class:`InputFormatError` naming ``key`` when it holds
    no real numbers (text, a cell array or struct, complex values: ``float()`` of them raises, or drops the
    imaginary part with only a warning). A ``.mat`` file is whatever MATLAB or ``scipy.io.savemat`` was
    given, so every variable is checked before a reader computes with it."""
    array = np.asarray(value)
    if array.dtype.kind not in _REAL:
        what = {"U": "text", "S": "text", "O": "a cell array or struct", "c": "complex numbers"}
        raise InputFormatError(
            f"holds {what.get(array.dtype.kind, array.dtype.name)}, expected real numbers", where, None, key
        )
    return array.astype(float)


def one_rate(value: Any, key: str, where: str) -> float:
    """The one rate (Hz) the variable ``key`` holds, within :data:`RATE_HZ`; :class:`InputFormatError`
    naming ``key`` otherwise (none, several, text, 0, inf, NaN, 1e300)."""
    rates = real_array(value, key, where).reshape(-1)
    if rates.size != 1:
        raise InputFormatError(f"{rates.size} values, expected one", where, None, key)
    rate = float(rates[0])
    if not RATE_HZ[0] <= rate <= RATE_HZ[1]:
        raise InputFormatError(
            f"rate {rate!r} Hz is outside {RATE_HZ[0]:g}-{RATE_HZ[1]:g} Hz", where, None, key
        )
    return rate
