"""Text encodings a log's files may be saved in, turned into the UTF-8 every reader parses.

- UTF-8, with or without a byte-order mark: the apps' own.
- UTF-16 (little or big endian) or UTF-32, with a byte-order mark: Excel's "Unicode text" (tab-separated
  UTF-16 LE), a Windows editor's "Unicode"; UTF-16 without one, told by its NUL bytes
  (:func:`unmarked_utf16`: a CSV's delimiters and digits are ASCII, whatever script its header is in).
  Transcoded to UTF-8 as the bytes are read
  (:func:`utf8_stream`: a piece at a time, never the file whole); bytes that are not text in the encoding
  the mark names (a lone surrogate, an odd byte at the end) are an
  :class:`~protocol.errors.InputFormatError` naming the file and the line.
- A legacy 8-bit encoding in a header (``µT`` or ``°/s`` saved by an old editor, or by Excel's "CSV" on
  Windows): read as Windows-1252 (:func:`decode_legacy`, Latin-1 where 1252 has no character), whose
  ``µ`` and ``°`` are Latin-1's. Which files are: :func:`hil.logs.table.text_lines` decides, from where
  the first byte that is not UTF-8 lies.
"""

from __future__ import annotations

import codecs
import io
from typing import IO

from hil.files.bounded import CHUNK_BYTES
from protocol.errors import InputFormatError

BOMS = (
    (codecs.BOM_UTF32_LE, "utf-32-le"),  # before UTF-16 LE's: FF FE 00 00 starts with FF FE
    (codecs.BOM_UTF32_BE, "utf-32-be"),
    (codecs.BOM_UTF16_LE, "utf-16-le"),
    (codecs.BOM_UTF16_BE, "utf-16-be"),
)
"""Byte-order marks of the wide encodings, and the codec each names."""
LEGACY = "cp1252"


def utf8_stream(raw: io.BufferedReader, where: str) -> IO[bytes]:
    """``raw``'s bytes as UTF-8: transcoded from UTF-16 or UTF-32 when a byte-order mark says so (the mark
    left out), else as they are (a UTF-8 mark is the readers' to skip)."""
    head = raw.peek(4)[:4]
    for bom, codec in BOMS:
        if head.startswith(bom):
            raw.read(len(bom))
            return io.BufferedReader(_Transcoder(raw, codec, where), 1 << 16)
    unmarked = unmarked_utf16(raw.peek(UNMARKED_PROBE)[:UNMARKED_PROBE])
    if unmarked is not None:
        return io.BufferedReader(_Transcoder(raw, unmarked, where), 1 << 16)
    return raw


UNMARKED_PROBE = 512
"""The first bytes :func:`unmarked_utf16` looks at: 256 characters of UTF-16 (a header and a row or two)."""
UNMARKED_ASCII_SHARE = 0.25
"""The least share of the probed characters that must be ASCII or Latin-1 (a NUL beside each) for text
without a byte-order mark to be UTF-16: a CSV's delimiters, digits, spaces and line breaks are, whatever
script its names are in (``Время;Ускорение X`` is 30 %, a data row nearly all)."""


def unmarked_utf16(head: bytes) -> str | None:
    """``"utf-16-le"`` or ``"utf-16-be"`` when ``head``, a file's first bytes, is UTF-16 without a
    byte-order mark (a tool's "Unicode" saved without one); else None. It is when it holds a NUL byte —
    which no UTF-8 text holds (the readers refuse a NUL as binary data) — and in that byte order the bytes
    are strict UTF-16 (a character cut at the probe's end aside) with no control character but tab, CR
    and LF, and at least
    :data:`UNMARKED_ASCII_SHARE` of the characters ASCII or Latin-1 (``µ``, ``°``). Any script may be in
    its header's names (Cyrillic, CJK, a ``µ`` first): only the NULs say the encoding."""
    head = head[: len(head) - len(head) % 2]
    if b"\x00" not in head:
        return None
    for codec in ("utf-16-le", "utf-16-be"):  # the other order makes ASCII CJK: the share tells them
        try:
            text = codecs.getincrementaldecoder(codec)("strict").decode(head, final=False)
        except UnicodeDecodeError:
            continue
        if not text or any((ord(c) < 0x20 and c not in "\t\r\n") or 0x7F <= ord(c) < 0xA0 for c in text):
            continue
        if sum(ord(c) < 0x100 for c in text) >= UNMARKED_ASCII_SHARE * len(text):
            return codec
    return None


def decode_legacy(data: bytes) -> str:
    """Bytes of a legacy 8-bit text: Windows-1252, or Latin-1 when a byte has no character in 1252."""
    try:
        return data.decode(LEGACY)
    except UnicodeDecodeError:
        return data.decode("latin-1")


def decode_text(data: bytes, final: bool = True) -> str:
    """UTF-8 text (a mark skipped), or the legacy 8-bit text it is when it is not UTF-8; ``final`` False
    for the first bytes of a file (a character cut at their end is no error)."""
    try:
        return codecs.getincrementaldecoder("utf-8-sig")().decode(data, final=final)
    except UnicodeDecodeError:
        return decode_legacy(data)


class _Transcoder(io.RawIOBase):
    """The bytes of ``raw`` (text in ``codec``, its mark read) as UTF-8, a piece at a time."""

    def __init__(self, raw: IO[bytes], codec: str, where: str) -> None:
        super().__init__()
        self._raw = raw
        self._codec = codec
        self._decoder = codecs.getincrementaldecoder(codec)("strict")
        self._where = where
        self._pending = b""
        self._line = 1
        self._ended = False

    def readable(self) -> bool:
        return True

    def readinto(self, buffer: memoryview) -> int:  # type: ignore[override]
        while not self._pending and not self._ended:
            piece = self._raw.read(CHUNK_BYTES)
            self._ended = not piece
            try:
                text = self._decoder.decode(piece, final=self._ended)
            except UnicodeDecodeError as exc:
                line = self._line + piece[: exc.start].decode(self._codec, "replace").count("\n")
                what = f"not {self._codec.upper()} text ({exc.reason})"
                raise InputFormatError(what, self._where, line) from None
            self._line += text.count("\n")
            self._pending = text.encode("utf-8")
        view = memoryview(buffer).cast("B")
        n = min(len(view), len(self._pending))
        view[:n] = self._pending[:n]
        self._pending = self._pending[n:]
        return n

    def close(self) -> None:
        try:
            self._raw.close()
        finally:
            super().close()
