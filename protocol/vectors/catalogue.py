"""Facts about the message catalogue that the vectors record and the checker compares: payload sizes,
the per-message summary rows, the names of header flags."""

from __future__ import annotations

from typing import Any

from ..fields import Blob, Scalar, Text, layout_of
from ..messages import CATALOGUE, Flags


def payload_size_range(cls: type) -> tuple[int, int]:
    """Smallest and largest payload (bytes) a message class can have on the wire."""
    lo = hi = 0
    for _, codec in layout_of(cls).fields:
        if isinstance(codec, Scalar):
            lo += codec.size
            hi += codec.size
        elif isinstance(codec, (Text, Blob)):
            lo += 1
            hi += 1 + codec.max_len
        else:
            item = codec.item
            size = item.size if isinstance(item, Scalar) else payload_size_range(item)[1]
            lo += 1 + codec.min_count * size
            hi += 1 + codec.max_count * size
    return lo, hi


def describe_catalogue() -> list[dict[str, Any]]:
    """One row per message, by id: name, id, reliable, smallest and largest payload."""
    rows = []
    for cls in sorted(CATALOGUE, key=lambda c: c.MSG_ID):
        lo, hi = payload_size_range(cls)
        rows.append(
            {
                "name": cls.__name__,
                "msg_id": cls.MSG_ID,
                "reliable": cls.RELIABLE,
                "payload_min": lo,
                "payload_max": hi,
            }
        )
    return rows


def flag_names(flags: int) -> list[str]:
    """Names of the :class:`~protocol.messages.Flags` bits set in ``flags``."""
    return [f.name for f in Flags if f.value and flags & f.value and f.name]
