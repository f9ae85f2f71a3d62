"""Message-specific codecs, generated once at import from the catalogue's layouts.

The generic interpreter in :mod:`protocol.fields` (``Layout.encode_into`` / ``Layout.decode_from``)
walks a message field by field; it is the reference, and the one place that words an error. This module
turns each message's :class:`~protocol.fields.Layout` into two straight-line Python functions, generated
as source text and compiled in memory (``compile``/``exec``) when ``protocol`` is imported:

* ``encode(msg, seq, flags) -> bytes | None`` — the frame body (4-byte header + payload) packed by one
  ``struct.Struct.pack`` call;
* ``decode(body) -> msg | None`` — the message in a frame body (header + payload, CRC removed) unpacked
  by one ``struct.Struct.unpack`` call.

A message's byte layout is fixed once the counts of its variable fields (arrays, text, blobs) are known:
e.g. a 4-unit ``ActuatorSetpoint`` is ``"<BBBB" + "BB" + "ff" * 4`` (header, mode, count, units). The
decoder reads those count bytes first, the encoder takes them from the values, and the ``struct.Struct``
for each combination of counts is built on first use and cached (at most :data:`STRUCT_CACHE` per
message, so hostile input cannot grow it).

Checks are cheap and total: enums by a 256-entry lookup table, ranges by comparisons against constants
(NaN fails every comparison), exact Python types on encode (``type(x) is float``; an enum field wants its
enum class); array items in a plain loop (measured faster on 1-16 items than ``min``/``max``/``map``).
Neither function builds error text: ``None`` says "not certainly valid" and sends the caller to the
reference, which raises the exact error — or, for the values the fast path does not take (an int in a
float field, a list for a tuple, a plain int for an enum member), encodes or decodes them as it always
did. Every message is decoded without calling its dataclass ``__init__``: the object is allocated and its
slots set directly (the classes are frozen, slotted and have no ``__post_init__``;
:func:`fast_constructor` checks that).
"""

from __future__ import annotations

import dataclasses
import operator
import struct
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

from .fields import _INT_BOUNDS, Array, Blob, Codec, Enum8, Layout, Scalar, Text, layout_of

HEADER_FORMAT = "<BBBB"
"""The frame header (version, msg_id, seq, flags) leads every message's struct; the decoder skips its values
(the caller has read them)."""
STRUCT_CACHE = 1024
"""Most structs kept per message (one per combination of variable-field counts seen)."""


@dataclass(frozen=True)
class MessageCodec:
    """The generated pair for one message class, and their source (for reading and debugging)."""

    encode: Callable[[Any, int, int], bytes | None]
    decode: Callable[[bytes], Any]
    source: str


@dataclass(frozen=True)
class _Part:
    """One field as the generator sees it. ``kind``: scalar, array (of scalars), records, text, blob."""

    kind: str
    name: str
    codec: Codec
    items: tuple[tuple[str, Scalar], ...] = ()  # a record's fields (kind "records") or the one scalar

    @property
    def variable(self) -> bool:
        return self.kind != "scalar"

    @property
    def item_format(self) -> str:
        return "".join(s.fmt for _, s in self.items)

    def format(self, count: int) -> str:
        if self.kind == "scalar":
            return self.item_format
        if self.kind in ("text", "blob"):
            return f"B{count}s"
        return "B" + self.item_format * count


def _parts(layout: Layout) -> list[_Part]:
    parts = []
    for name, codec in layout.fields:
        if isinstance(codec, Scalar):
            parts.append(_Part("scalar", name, codec, ((name, codec),)))
        elif isinstance(codec, Text):
            parts.append(_Part("text", name, codec))
        elif isinstance(codec, Blob):
            parts.append(_Part("blob", name, codec))
        elif isinstance(codec.item, Scalar):
            parts.append(_Part("array", name, codec, (("", codec.item),)))
        else:
            record = layout_of(codec.item)
            if not all(isinstance(c, Scalar) for _, c in record.fields):
                raise TypeError(f"{layout.name}.{name}: records of records are not supported")
            parts.append(_Part("records", name, codec, tuple(record.fields)))  # type: ignore[arg-type]
    return parts


def _count_range(part: _Part) -> tuple[int, int]:
    codec = part.codec
    if isinstance(codec, Array):
        return codec.min_count, codec.max_count
    assert isinstance(codec, (Text, Blob))
    return 0, codec.max_len


def _fast_new(cls: type) -> tuple[Callable[..., Any], list[Callable[[Any, Any], None]]]:
    """``object.__new__`` and the slot setters of a frozen, slotted dataclass without ``__post_init__``."""
    params = getattr(cls, "__dataclass_params__", None)
    if params is None or not params.frozen or "__slots__" not in cls.__dict__:
        raise TypeError(f"{cls.__name__} is not a frozen, slotted dataclass")
    if hasattr(cls, "__post_init__"):
        raise TypeError(f"{cls.__name__} has a __post_init__: it must be built through __init__")
    setters = [cls.__dict__[f.name].__set__ for f in dataclasses.fields(cls)]
    return object.__new__, setters


class _Source:
    """Generated source text and the constants it refers to by name."""

    def __init__(self) -> None:
        self.lines: list[str] = []
        self.names: dict[str, Any] = {}
        self._ids: dict[int, str] = {}

    def line(self, indent: int, text: str) -> None:
        self.lines.append("    " * indent + text)

    def const(self, value: Any, hint: str) -> str:
        """A name for ``value`` in the generated module (one name per object)."""
        key = id(value)
        if key not in self._ids:
            self._ids[key] = name = f"{hint}{len(self._ids)}"
            self.names[name] = value
        return self._ids[key]


def _literal(scalar: Scalar, value: float) -> str:
    return repr(float(value)) if scalar.fmt == "f" else repr(int(value))


def _narrow(scalar: Scalar) -> bool:
    """True if the field's range is narrower than its wire type's (so a decoded value needs a check)."""
    return scalar.fmt == "f" or (scalar.lo, scalar.hi) != _INT_BOUNDS[scalar.fmt]


def _enum_table(codec: Enum8) -> tuple[Any, ...]:
    """Index = wire byte, value = the enum member or None."""
    members = {int(m): m for m in codec.enum_cls}
    return tuple(members.get(v) for v in range(256))


# =========================================================================== decode
def _gen_decode(src: _Source, cls: type, parts: list[_Part]) -> None:
    src.line(0, "def decode(b):")
    counts: list[str] = []
    if any(p.variable for p in parts):
        src.line(1, "n = len(b)")
        step = "4"  # from the last count byte (or the frame's start) to the next count byte
        for part in parts:
            if not part.variable:
                step = _plus(step, struct.calcsize("<" + part.format(0)))
                continue
            c = f"c{len(counts)}"
            src.line(1, f"p = {step}" if not counts else f"p += {step}")
            src.line(1, "if p >= n:")
            src.line(2, "return None")
            src.line(1, f"{c} = b[p]")
            lo, hi = _count_range(part)
            bad = f"{c} > {hi}" if lo == 0 else f"{c} < {lo} or {c} > {hi}"
            if (lo, hi) != (0, 255):
                src.line(1, f"if {bad}:")
                src.line(2, "return None")
            size = struct.calcsize("<" + part.item_format) if part.item_format else 1
            step = f"1 + {c}" if size == 1 else f"1 + {c} * {size}"
            counts.append(c)
        key = _key(counts)
        src.line(1, f"st = STRUCTS.get({key})")
        src.line(1, "if st is None:")
        src.line(2, f"st = build({key})")
        src.line(1, "if st.size != n:")
        src.line(2, "return None")
        src.line(1, "v = st.unpack(b)")
    else:
        src.line(1, f"if len(b) != {src.names['ST'].size}:")
        src.line(2, "return None")
        src.line(1, "v = ST.unpack(b)")
    values = _gen_decode_values(src, parts, counts)
    new, setters = _fast_new(cls)
    src.names["new"] = new
    src.line(1, f"o = new({src.const(cls, 'C')})")
    for setter, value in zip(setters, values, strict=True):
        src.line(1, f"{src.const(setter, 'set')}(o, {value})")
    src.line(1, "return o")


def _gen_decode_values(src: _Source, parts: list[_Part], counts: list[str]) -> list[str]:
    """Emit the checks of the unpacked tuple ``v``; return each field's value expression."""
    values: list[str] = []
    bad: list[str] = []  # conditions of consecutive scalars, emitted as one test
    index = "4"  # index in v of the part's first value (after the header's four); an expression after arrays
    var = 0
    for n, part in enumerate(parts):
        x = f"x{n}"
        if part.kind == "scalar":
            scalar = part.items[0][1]
            if isinstance(scalar, Enum8):
                src.line(1, f"{x} = {src.const(_enum_table(scalar), 'E')}[v[{index}]]")
                bad.append(f"{x} is None")
            elif _narrow(scalar):
                src.line(1, f"{x} = v[{index}]")
                bad.append(f"not {_literal(scalar, scalar.lo)} <= {x} <= {_literal(scalar, scalar.hi)}")
            else:
                x = f"v[{index}]"
            values.append(x)
            index = _plus(index, 1)
            continue
        _reject_if(src, bad)
        c = counts[var]
        var += 1
        if part.kind in ("text", "blob"):  # two values: the count and the bytes
            raw = f"v[{_plus(index, 1)}]"
            if part.kind == "text":
                src.line(1, "try:")
                src.line(2, f"{x} = {raw}.decode()")
                src.line(1, "except UnicodeDecodeError:")
                src.line(2, "return None")
            else:
                x = raw
            values.append(x)
            index = _plus(index, 2)
            continue
        k = len(part.items)
        start = _plus(index, 1)
        end = f"{start} + {c}" + (f" * {k}" if k > 1 else "")
        if part.kind == "array":
            _gen_decode_column(src, part.items[0][1], f"v[{start}:{end}]", x)
        else:
            assert isinstance(part.codec, Array) and isinstance(part.codec.item, type)
            _gen_decode_records(src, part.codec.item, part.items, f"v[{start}:{end}]", x)
        values.append(x)
        if n + 1 < len(parts):
            src.line(1, f"i{var} = {end}")
            index = f"i{var}"
    _reject_if(src, bad)
    return values


def _gen_decode_column(src: _Source, scalar: Scalar, values: str, x: str) -> None:
    """``x`` = the tuple ``values`` of an array of scalars, checked."""
    src.line(1, f"{x} = {values}")
    if isinstance(scalar, Enum8):
        src.line(1, f"{x} = tuple(map({src.const(_enum_table(scalar), 'E')}.__getitem__, {x}))")
        src.line(1, f"if None in {x}:")
        src.line(2, "return None")
    elif scalar.fmt == "f":  # a loop: min and max cannot see a NaN
        src.line(1, f"for a in {x}:")
        src.line(2, f"if not {_literal(scalar, scalar.lo)} <= a <= {_literal(scalar, scalar.hi)}:")
        src.line(3, "return None")
    elif _narrow(scalar):
        lo, hi = _literal(scalar, scalar.lo), _literal(scalar, scalar.hi)
        src.line(1, f"if {x} and (min({x}) < {lo} or max({x}) > {hi}):")
        src.line(2, "return None")


def _gen_decode_records(
    src: _Source, cls: type, items: tuple[tuple[str, Scalar], ...], values: str, x: str
) -> None:
    """``x`` = the tuple of records ``cls`` made of the flat tuple ``values``, checked."""
    names = [f"a{j}" for j in range(len(items))]
    src.line(1, "out = []")
    src.line(1, f"it = iter({values})")
    src.line(
        1,
        f"for {', '.join(names)} in zip({', '.join(['it'] * len(items))}):"
        if len(items) > 1
        else "for a0 in it:",
    )
    bad = []
    for a, (_, scalar) in zip(names, items, strict=True):
        if isinstance(scalar, Enum8):
            src.line(2, f"{a} = {src.const(_enum_table(scalar), 'E')}[{a}]")
            bad.append(f"{a} is None")
        elif _narrow(scalar):
            bad.append(f"not {_literal(scalar, scalar.lo)} <= {a} <= {_literal(scalar, scalar.hi)}")
    if bad:
        src.line(2, f"if {' or '.join(bad)}:")
        src.line(3, "return None")
    _, setters = _fast_new(cls)
    src.line(2, f"r = new({src.const(cls, 'C')})")
    for setter, a in zip(setters, names, strict=True):
        src.line(2, f"{src.const(setter, 'set')}(r, {a})")
    src.line(2, "out.append(r)")
    src.line(1, f"{x} = tuple(out)")


def _reject_if(src: _Source, conditions: list[str]) -> None:
    """Emit one ``if a or b ...: return None`` and empty the list."""
    if conditions:
        src.line(1, f"if {' or '.join(conditions)}:")
        src.line(2, "return None")
        conditions.clear()


def _key(counts: list[str]) -> str:
    """The struct cache's key: the one count, or the tuple of them."""
    return counts[0] if len(counts) == 1 else "(" + ", ".join(counts) + ")"


def _plus(index: str, n: int) -> str:
    if index.isdigit():
        return str(int(index) + n)
    head, _, tail = index.rpartition(" + ")
    if tail.isdigit() and head:
        return f"{head} + {int(tail) + n}"
    return f"{index} + {n}"


def fast_constructor(cls: type) -> Callable[..., Any]:
    """A function building an instance of ``cls`` (a frozen, slotted dataclass without ``__post_init__``)
    from all its field values, positionally, by setting its slots (see the module docstring)."""
    new, setters = _fast_new(cls)
    args = ", ".join(f"a{i}" for i in range(len(setters)))
    body = "".join(f"    s{i}(o, a{i})\n" for i in range(len(setters)))
    namespace: dict[str, Any] = {"new": new, "C": cls, **{f"s{i}": s for i, s in enumerate(setters)}}
    exec(f"def make({args}):\n    o = new(C)\n{body}    return o\n", namespace)  # noqa: S102
    return namespace["make"]  # type: ignore[no-any-return]


# =========================================================================== encode
def _gen_encode(src: _Source, cls: type, msg_id: int, version: int, parts: list[_Part]) -> None:
    src.line(0, "def encode(m, seq, flags):")
    src.line(1, f"if type(m) is not {src.const(cls, 'C')}:")
    src.line(2, "return None")
    xs = [f"x{i}" for i in range(len(parts))]
    if len(parts) == 1:
        src.line(1, f"x0 = m.{parts[0].name}")
    elif parts:
        getter = src.const(operator.attrgetter(*[p.name for p in parts]), "get")
        src.line(1, f"{', '.join(xs)} = {getter}(m)")
    args = [str(version), str(msg_id), "seq", "flags"]
    counts: list[str] = []
    good: list[str] = []  # conditions of consecutive scalars, emitted as one test
    struct_error = False  # does a full-range integer rely on struct's own range check?
    for part, x in zip(parts, xs, strict=True):
        if part.kind == "scalar":
            scalar = part.items[0][1]
            good.append(_scalar_ok(src, scalar, x))
            struct_error |= not isinstance(scalar, Enum8) and not _narrow(scalar)
            args.append(x)
            continue
        if good:
            src.line(1, f"if not ({' and '.join(good)}):")
            src.line(2, "return None")
            good.clear()
        c = f"c{len(counts)}"
        counts.append(c)
        want = {"text": "str", "blob": "bytes"}.get(part.kind, "tuple")
        src.line(1, f"if type({x}) is not {want}:")
        src.line(2, "return None")
        if part.kind == "text":
            src.line(1, "try:")
            src.line(2, f"{x} = {x}.encode()")
            src.line(1, "except UnicodeEncodeError:")
            src.line(2, "return None")
        src.line(1, f"{c} = len({x})")
        lo, hi = _count_range(part)
        src.line(1, f"if {c} > {hi}:" if lo == 0 else f"if {c} < {lo} or {c} > {hi}:")
        src.line(2, "return None")
        if part.kind in ("text", "blob"):
            args += [c, x]
            continue
        if part.kind == "array":
            scalar = part.items[0][1]
            src.line(1, f"for a in {x}:")
            src.line(2, f"if not ({_scalar_ok(src, scalar, 'a')}):")
            src.line(3, "return None")
            args += [c, f"*{x}"]
        else:
            assert isinstance(part.codec, Array) and isinstance(part.codec.item, type)
            args += [c, f"*{_gen_encode_records(src, part.codec.item, part.items, x)}"]
        struct_error |= any(not isinstance(s, Enum8) and not _narrow(s) for _, s in part.items)
    if good:
        src.line(1, f"if not ({' and '.join(good)}):")
        src.line(2, "return None")
    if counts:
        src.line(1, f"st = STRUCTS.get({_key(counts)})")
        src.line(1, "if st is None:")
        src.line(2, f"st = build({_key(counts)})")
    pack = f"{'st' if counts else 'ST'}.pack({', '.join(args)})"
    if struct_error:
        src.names["StructError"] = struct.error
        src.line(1, "try:")
        src.line(2, f"return {pack}")
        src.line(1, "except StructError:  # a full-range integer outside its wire type")
        src.line(2, "return None")
    else:
        src.line(1, f"return {pack}")


def _gen_encode_records(src: _Source, cls: type, items: tuple[tuple[str, Scalar], ...], x: str) -> str:
    """Check the records in the tuple ``x`` and gather their values; returns the list's name."""
    flat = f"f{x}"
    names = [f"a{j}" for j in range(len(items))]
    src.line(1, f"{flat} = []")
    src.line(1, f"for r in {x}:")
    src.line(2, f"if type(r) is not {src.const(cls, 'R')}:")
    src.line(3, "return None")
    for a, (name, _) in zip(names, items, strict=True):
        src.line(2, f"{a} = r.{name}")
    good = [_scalar_ok(src, scalar, a) for a, (_, scalar) in zip(names, items, strict=True)]
    src.line(2, f"if not ({' and '.join(good)}):")
    src.line(3, "return None")
    src.line(2, f"{flat} += ({', '.join(names)},)")
    return flat


def _wire_type(scalar: Scalar) -> type:
    """The exact Python type the encoder's fast path takes for a field (others go to the reference)."""
    if isinstance(scalar, Enum8):
        return scalar.enum_cls
    return float if scalar.fmt == "f" else int


def _scalar_ok(src: _Source, scalar: Scalar, x: str) -> str:
    want = src.const(_wire_type(scalar), "T")
    if isinstance(scalar, Enum8) or not _narrow(scalar):
        return f"type({x}) is {want}"
    lo, hi = _literal(scalar, scalar.lo), _literal(scalar, scalar.hi)
    return f"type({x}) is {want} and {lo} <= {x} <= {hi}"


# =========================================================================== the pair
class CodecTable(Mapping[int, MessageCodec]):
    """Message id → the message's generated codec (:func:`compile_message`), each generated on its first
    look-up: generating and compiling all of the catalogue's took ~8 ms of every process's import of
    ``protocol`` (issue 29: the imports before a run's first tick), and a run uses half of its messages.
    Every id of ``classes`` is a key from the start (iteration, ``in`` and ``len`` generate nothing)."""

    def __init__(self, classes: Mapping[int, type], version: int) -> None:
        self._classes = dict(classes)
        self._version = version
        self._made: dict[int, MessageCodec] = {}

    def __getitem__(self, msg_id: int) -> MessageCodec:
        codec = self._made.get(msg_id)
        if codec is None:  # two threads may both generate one: the same functions, one of them kept
            codec = self._made[msg_id] = compile_message(self._classes[msg_id], msg_id, self._version)
        return codec

    def __iter__(self) -> Iterator[int]:
        return iter(self._classes)

    def __len__(self) -> int:
        return len(self._classes)


def compile_message(cls: type, msg_id: int, version: int) -> MessageCodec:
    """Generate, compile and return the encoder and decoder of message class ``cls``."""
    layout = layout_of(cls)
    parts = _parts(layout)
    variable = [p for p in parts if p.variable]
    structs: dict[Any, struct.Struct] = {}

    def struct_of(*counts: int) -> struct.Struct:
        it = iter(counts)
        return struct.Struct(HEADER_FORMAT + "".join(p.format(next(it) if p.variable else 0) for p in parts))

    def build(key: Any) -> struct.Struct:
        if len(structs) >= STRUCT_CACHE:
            structs.clear()
        st = structs[key] = struct_of(*(key if isinstance(key, tuple) else (key,)))
        return st

    src = _Source()
    src.names.update(STRUCTS=structs, build=build)
    if not variable:
        src.names["ST"] = struct_of()
    _gen_encode(src, cls, msg_id, version, parts)
    src.line(0, "")
    _gen_decode(src, cls, parts)
    text = "\n".join(src.lines) + "\n"
    namespace = dict(src.names)
    exec(compile(text, f"<protocol.compiled {cls.__name__}>", "exec"), namespace)  # noqa: S102
    return MessageCodec(namespace["encode"], namespace["decode"], text)
