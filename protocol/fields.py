"""Wire types for message fields, and the layout compiler that turns a message dataclass into a codec.

A message is a frozen dataclass whose fields are declared with :func:`wire`, e.g.
``voltage_mv: int = wire(U16(0, 60000, unit="mV"))``. The field order is the wire order; all numbers are
little-endian. Consecutive fixed-size scalars are packed with one precompiled ``struct.Struct`` so that a
message costs a handful of C calls to encode or decode.

Every codec checks ranges in both directions: encoding a bad value raises :class:`FieldRangeError`, and so
does decoding one (the deframer turns that into a bad-frame event with reason ``FIELD_RANGE``). NaN and
infinities are out of range for every float field. Each codec has a ``signature()`` that the schema hash
is computed from, so changing a type, range or enum changes the hash.
"""

from __future__ import annotations

import dataclasses
import enum
import math
import operator
import struct
from collections.abc import Sequence, Sized
from typing import Any

from .errors import FieldRangeError, ProtocolError
from .numbers import real_number, whole_number

_INT_BOUNDS = {
    "B": (0, 0xFF),
    "H": (0, 0xFFFF),
    "I": (0, 0xFFFFFFFF),
    "b": (-0x80, 0x7F),
    "h": (-0x8000, 0x7FFF),
    "i": (-0x80000000, 0x7FFFFFFF),
}
_F32_MAX = 3.4028234663852886e38


class Scalar:
    """A fixed-size number: ``fmt`` is a ``struct`` code (B H I b h i f)."""

    def __init__(
        self,
        fmt: str,
        lo: float | None = None,
        hi: float | None = None,
        unit: str = "",
        doc: str = "",
    ) -> None:
        self.fmt = fmt
        self.size = struct.calcsize("<" + fmt)
        if fmt == "f":
            tlo, thi = -_F32_MAX, _F32_MAX
        else:
            tlo, thi = _INT_BOUNDS[fmt]
        self.lo = tlo if lo is None else lo
        self.hi = thi if hi is None else hi
        self.unit = unit
        self.doc = doc

    def check(self, value: Any) -> bool:
        """True if ``value`` may be sent in this field."""
        if self.fmt == "f":
            if isinstance(value, float):
                return math.isfinite(value) and self.lo <= value <= self.hi
            # any real number as the float it is (an int, numpy's float32, a 0-d array: what
            # :func:`real_number` takes; not a bool or a string): 10**400 was an OverflowError out of
            # math.isfinite, and numpy's float32 1.0, what a float32 controller computes, was refused as
            # "out of range"
            number = real_number(value)
            return number is not None and math.isfinite(number) and self.lo <= number <= self.hi
        whole = whole_number(value)  # numpy's integers too: struct packs them by ``__index__``
        return whole is not None and self.lo <= whole <= self.hi

    def from_wire(self, value: Any) -> Any:
        return value

    def to_wire(self, value: Any) -> Any:
        return value

    def type_name(self) -> str:
        return {"B": "u8", "H": "u16", "I": "u32", "b": "i8", "h": "i16", "i": "i32", "f": "f32"}[self.fmt]

    def signature(self) -> str:
        return f"{self.type_name()}[{self.lo:g},{self.hi:g}]"


class U8(Scalar):
    def __init__(self, lo: int = 0, hi: int = 0xFF, unit: str = "", doc: str = "") -> None:
        super().__init__("B", lo, hi, unit, doc)


class U16(Scalar):
    def __init__(self, lo: int = 0, hi: int = 0xFFFF, unit: str = "", doc: str = "") -> None:
        super().__init__("H", lo, hi, unit, doc)


class U32(Scalar):
    def __init__(self, lo: int = 0, hi: int = 0xFFFFFFFF, unit: str = "", doc: str = "") -> None:
        super().__init__("I", lo, hi, unit, doc)


class I16(Scalar):
    def __init__(self, lo: int = -0x8000, hi: int = 0x7FFF, unit: str = "", doc: str = "") -> None:
        super().__init__("h", lo, hi, unit, doc)


class F32(Scalar):
    """IEEE-754 binary32. Values are rounded to float32 on the wire; decoded values are Python floats."""

    def __init__(self, lo: float, hi: float, unit: str = "", doc: str = "") -> None:
        super().__init__("f", lo, hi, unit, doc)


class Enum8(Scalar):
    """A u8 whose value must be a member of ``enum_cls`` (an ``IntEnum``)."""

    def __init__(self, enum_cls: type[enum.IntEnum], doc: str = "") -> None:
        values = [int(m) for m in enum_cls]
        super().__init__("B", min(values), max(values), "", doc)
        self.enum_cls = enum_cls
        self._values = frozenset(values)

    def check(self, value: Any) -> bool:
        if type(value) is int or isinstance(value, self.enum_cls):  # the hot path: every decoded enum
            return value in self._values
        return whole_number(value) in self._values

    def from_wire(self, value: Any) -> Any:
        return self.enum_cls(value)

    def to_wire(self, value: Any) -> Any:
        return int(value)

    def signature(self) -> str:
        members = ",".join(f"{m.name}={int(m)}" for m in self.enum_cls)
        return f"enum8{{{members}}}"


class Text:
    """UTF-8 text: a u8 byte count then the bytes (no terminator). At most ``max_len`` bytes."""

    def __init__(self, max_len: int, doc: str = "") -> None:
        self.max_len = max_len
        self.doc = doc

    def check(self, value: Any) -> bool:
        if not isinstance(value, str):
            return False
        try:
            return len(value.encode("utf-8")) <= self.max_len
        except UnicodeEncodeError:
            return False

    def encode(self, value: str, out: bytearray) -> None:
        raw = value.encode("utf-8")
        out.append(len(raw))
        out += raw

    def decode(self, buf: bytes, offset: int) -> tuple[str, int]:
        n = _read_count(buf, offset)
        end = offset + 1 + n
        if end > len(buf):
            raise _Short()
        try:
            value = buf[offset + 1 : end].decode("utf-8")
        except UnicodeDecodeError as exc:
            raise _Invalid(f"invalid UTF-8 ({exc.reason})") from exc
        if n > self.max_len:
            raise _Invalid(f"{n} bytes > {self.max_len}")
        return value, end

    def signature(self) -> str:
        return f"text[{self.max_len}]"


class Blob:
    """Raw bytes: a u8 byte count then the bytes. At most ``max_len`` bytes."""

    def __init__(self, max_len: int, doc: str = "") -> None:
        self.max_len = max_len
        self.doc = doc

    def check(self, value: Any) -> bool:
        return isinstance(value, (bytes, bytearray)) and len(value) <= self.max_len

    def encode(self, value: bytes, out: bytearray) -> None:
        out.append(len(value))
        out += value

    def decode(self, buf: bytes, offset: int) -> tuple[bytes, int]:
        n = _read_count(buf, offset)
        end = offset + 1 + n
        if end > len(buf):
            raise _Short()
        if n > self.max_len:
            raise _Invalid(f"{n} bytes > {self.max_len}")
        return bytes(buf[offset + 1 : end]), end

    def signature(self) -> str:
        return f"blob[{self.max_len}]"


class Array:
    """A u8 element count then that many elements; ``item`` is a :class:`Scalar` or a record dataclass."""

    def __init__(self, item: Scalar | type, min_count: int, max_count: int, doc: str = "") -> None:
        self.item = item
        self.min_count = min_count
        self.max_count = max_count
        self.doc = doc
        if isinstance(item, Scalar):
            self._layout: Layout | None = None
            self._struct = struct.Struct("<" + item.fmt)
        else:
            self._layout = layout_of(item)
            self._struct = None  # type: ignore[assignment]

    def check_count(self, n: int) -> bool:
        return self.min_count <= n <= self.max_count

    def signature(self) -> str:
        inner = self.item.signature() if isinstance(self.item, Scalar) else layout_of(self.item).signature()
        return f"array[{self.min_count}..{self.max_count}]<{inner}>"


Codec = Scalar | Text | Blob | Array


class _Short(Exception):
    """Internal: the payload ended inside a field."""


class _Invalid(Exception):
    """Internal: a variable-length field's content is invalid."""


def _read_count(buf: bytes, offset: int) -> int:
    if offset >= len(buf):
        raise _Short()
    return buf[offset]


def wire(codec: Codec, default: Any = dataclasses.MISSING) -> Any:
    """Declare a dataclass field's wire type (use as the field's default value)."""
    if default is dataclasses.MISSING:
        return dataclasses.field(metadata={"wire": codec})
    if isinstance(default, (list, dict, set)):
        raise TypeError("use a tuple (immutable) default")
    return dataclasses.field(default=default, metadata={"wire": codec})


class PayloadLengthError(ProtocolError):
    """The payload is shorter or longer than its fields (bad-frame reason ``LENGTH``)."""


@dataclasses.dataclass
class _StructRun:
    """Consecutive scalar fields packed by one ``struct.Struct``, with their checks precomputed.

    Hot path of every encode and decode: a value of exactly the wire type inside ``bounds`` passes
    with one comparison (NaN fails every comparison and ±inf lies outside every float range); anything
    else goes through the codec's full ``check``. Enum fields are always checked for membership."""

    names: tuple[str, ...]
    codecs: tuple[Scalar, ...]
    packer: struct.Struct

    def __post_init__(self) -> None:
        self.bounds = tuple((c.lo, c.hi) for c in self.codecs)
        # The exact Python type that may take the fast path (None: enums, always fully checked).
        self.fast_types = tuple(
            None if isinstance(c, Enum8) else (float if c.fmt == "f" else int) for c in self.codecs
        )
        self.enums = tuple((i, c) for i, c in enumerate(self.codecs) if isinstance(c, Enum8))
        getter = operator.attrgetter(*self.names)
        self.values_of = getter if len(self.names) > 1 else (lambda obj: (getter(obj),))


class Layout:
    """Encoder/decoder for one dataclass (a message or an array record)."""

    def __init__(self, cls: type) -> None:
        self.cls = cls
        self.fields: list[tuple[str, Codec]] = []
        for f in dataclasses.fields(cls):
            codec = f.metadata.get("wire")
            if codec is None:
                raise TypeError(f"{cls.__name__}.{f.name} has no wire type")
            self.fields.append((f.name, codec))
        self._steps: list[_StructRun | tuple[str, Codec]] = []
        run: list[tuple[str, Scalar]] = []
        for name, codec in self.fields:
            if isinstance(codec, Scalar):
                run.append((name, codec))
                continue
            self._flush(run)
            run = []
            self._steps.append((name, codec))
        self._flush(run)
        self.fixed_size = sum(c.size for _, c in self.fields if isinstance(c, Scalar))

    def _flush(self, run: list[tuple[str, Scalar]]) -> None:
        if run:
            fmt = "<" + "".join(c.fmt for _, c in run)
            self._steps.append(
                _StructRun(tuple(n for n, _ in run), tuple(c for _, c in run), struct.Struct(fmt))
            )

    @property
    def name(self) -> str:
        return self.cls.__name__

    def signature(self) -> str:
        return "{" + ",".join(f"{n}:{c.signature()}" for n, c in self.fields) + "}"

    # ----------------------------------------------------------------- encode
    def encode_into(self, obj: Any, out: bytearray, where: str) -> None:
        for step in self._steps:
            if isinstance(step, _StructRun):
                values = step.values_of(obj)
                for v, (lo, hi), fast, scalar, field_name in zip(
                    values, step.bounds, step.fast_types, step.codecs, step.names, strict=True
                ):
                    if type(v) is fast and lo <= v <= hi:
                        continue
                    if not scalar.check(v):
                        raise FieldRangeError(where, field_name, v)
                out += step.packer.pack(*values)  # struct takes int subclasses (IntEnum) as they are
                continue
            name, codec = step
            v = getattr(obj, name)
            if isinstance(codec, Array):
                self._encode_array(codec, v, out, where, name)
            else:
                assert isinstance(codec, (Text, Blob))  # scalars are always in a struct run
                if not codec.check(v):
                    raise FieldRangeError(where, name, v)
                codec.encode(v, out)

    @staticmethod
    def _encode_array(codec: Array, items: Sequence[Any], out: bytearray, owner: str, name: str) -> None:
        if not isinstance(items, (tuple, list)) or not codec.check_count(len(items)):
            raise FieldRangeError(owner, f"{name} (count)", len(items) if isinstance(items, Sized) else items)
        out.append(len(items))
        layout = codec._layout
        if layout is None:
            item = codec.item
            assert isinstance(item, Scalar)
            for i, v in enumerate(items):
                if not item.check(v):
                    raise FieldRangeError(owner, f"{name}[{i}]", v)
                out += codec._struct.pack(item.to_wire(v))
            return
        for i, v in enumerate(items):
            if not isinstance(v, layout.cls):
                raise FieldRangeError(owner, f"{name}[{i}]", v)
            layout.encode_into(v, out, f"{owner}.{name}[{i}]")

    # ----------------------------------------------------------------- decode
    def decode_from(self, buf: bytes, offset: int, where: str) -> tuple[Any, int]:
        kwargs: dict[str, Any] = {}
        for step in self._steps:
            if isinstance(step, _StructRun):
                end = offset + step.packer.size
                if end > len(buf):
                    raise PayloadLengthError(f"{where}: payload ends inside {step.names[0]}")
                unpacked = step.packer.unpack_from(buf, offset)
                offset = end
                # Unpacked values are exactly int or float: the bounds are the whole check.
                for v, (lo, hi), field_name in zip(unpacked, step.bounds, step.names, strict=True):
                    if not lo <= v <= hi:
                        raise FieldRangeError(where, field_name, v)
                kwargs.update(zip(step.names, unpacked, strict=True))
                for i, enum_codec in step.enums:
                    field_name, v = step.names[i], unpacked[i]
                    if not enum_codec.check(v):
                        raise FieldRangeError(where, field_name, v)
                    kwargs[field_name] = enum_codec.from_wire(v)
                continue
            name, codec = step
            try:
                if isinstance(codec, Array):
                    kwargs[name], offset = self._decode_array(codec, buf, offset, where, name)
                else:
                    assert isinstance(codec, (Text, Blob))  # scalars are always in a struct run
                    kwargs[name], offset = codec.decode(buf, offset)
            except _Short:
                raise PayloadLengthError(f"{where}: payload ends inside {name}") from None
            except _Invalid as exc:
                raise FieldRangeError(where, name, str(exc)) from None
        return self.cls(**kwargs), offset

    @staticmethod
    def _decode_array(
        codec: Array, buf: bytes, offset: int, owner: str, name: str
    ) -> tuple[tuple[Any, ...], int]:
        n = _read_count(buf, offset)
        offset += 1
        if not codec.check_count(n):
            raise _Invalid(f"count {n} not in {codec.min_count}..{codec.max_count}")
        items: list[Any] = []
        layout = codec._layout
        if layout is None:
            item = codec.item
            assert isinstance(item, Scalar)
            size = codec._struct.size
            if offset + n * size > len(buf):
                raise _Short()
            for i, (v,) in enumerate(codec._struct.iter_unpack(buf[offset : offset + n * size])):
                if not item.check(v):
                    raise FieldRangeError(owner, f"{name}[{i}]", v)
                items.append(item.from_wire(v))
            return tuple(items), offset + n * size
        for i in range(n):
            try:
                v, offset = layout.decode_from(buf, offset, f"{owner}.{name}[{i}]")
            except PayloadLengthError:
                raise _Short() from None
            items.append(v)
        return tuple(items), offset


_LAYOUTS: dict[type, Layout] = {}


def layout_of(cls: type) -> Layout:
    """The (cached) compiled layout of a wire dataclass."""
    layout = _LAYOUTS.get(cls)
    if layout is None:
        layout = _LAYOUTS[cls] = Layout(cls)
    return layout
