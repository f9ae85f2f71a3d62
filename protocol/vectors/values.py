"""Field values <-> JSON: how the vectors file writes a message's fields, and strictly reads them back.

Integers are numbers, enums ``{"name", "value"}``, text strings, blobs lowercase hex, records objects,
arrays lists; floats are the double holding the float32 value.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from ..errors import ProtocolError, value_repr
from ..fields import Array, Blob, Enum8, Scalar, Text, layout_of


def to_json(obj: Any) -> dict[str, Any]:
    """The JSON-friendly field values of a message or record dataclass (wire order)."""
    return {name: _value_to_json(codec, getattr(obj, name)) for name, codec in layout_of(type(obj)).fields}


def _value_to_json(codec: Any, value: Any) -> Any:
    if isinstance(codec, Enum8):
        return {"name": codec.enum_cls(value).name, "value": int(value)}
    if isinstance(codec, Blob):
        return bytes(value).hex()
    if isinstance(codec, Array):
        if isinstance(codec.item, Scalar):
            return [_value_to_json(codec.item, v) for v in value]
        return [to_json(v) for v in value]
    if isinstance(codec, Scalar) and codec.fmt == "f":
        return float(value)
    return value  # int or str


def from_json(cls: type, values: Mapping[str, Any], where: str = "") -> Any:
    """Build ``cls`` (a message or record dataclass) from :func:`to_json`'s form.

    Strict: a missing or unknown key, a wrong JSON type or an enum whose name and value disagree raises
    :class:`ProtocolError` naming the path (``where``). Ranges are *not* checked here: encoding does that.
    """
    where = where or cls.__name__
    if not isinstance(values, Mapping):
        raise ProtocolError(f"{where}: expected an object, got {type(values).__name__}")
    layout = layout_of(cls)
    names = [name for name, _ in layout.fields]
    extra = sorted(set(values) - set(names))
    missing = [n for n in names if n not in values]
    if extra or missing:
        raise ProtocolError(f"{where}: unknown field(s) {extra}, missing field(s) {missing}")
    kwargs = {name: _value_from_json(codec, values[name], f"{where}.{name}") for name, codec in layout.fields}
    return cls(**kwargs)


def _value_from_json(codec: Any, value: Any, where: str) -> Any:
    if isinstance(codec, Enum8):
        if not isinstance(value, Mapping) or set(value) != {"name", "value"}:
            raise ProtocolError(f"{where}: expected {{'name', 'value'}}, got {value_repr(value)}")
        try:
            member = codec.enum_cls[value["name"]]
        except KeyError:
            raise ProtocolError(
                f"{where}: {value_repr(value['name'])} is not a {codec.enum_cls.__name__}"
            ) from None
        if int(member) != value["value"]:
            raise ProtocolError(f"{where}: {member.name} is {int(member)}, not {value_repr(value['value'])}")
        return member
    if isinstance(codec, Blob):
        if not isinstance(value, str):
            raise ProtocolError(f"{where}: expected a hex string, got {value_repr(value)}")
        try:
            return bytes.fromhex(value)
        except ValueError:
            raise ProtocolError(f"{where}: {value_repr(value)} is not hex") from None
    if isinstance(codec, Text):
        if not isinstance(value, str):
            raise ProtocolError(f"{where}: expected a string, got {value_repr(value)}")
        return value
    if isinstance(codec, Array):
        if not isinstance(value, list):
            raise ProtocolError(f"{where}: expected a list, got {value_repr(value)}")
        if isinstance(codec.item, Scalar):
            return tuple(_value_from_json(codec.item, v, f"{where}[{i}]") for i, v in enumerate(value))
        return tuple(from_json(codec.item, v, f"{where}[{i}]") for i, v in enumerate(value))
    if codec.fmt == "f":
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ProtocolError(f"{where}: expected a number, got {value_repr(value)}")
        return float(value)
    if isinstance(value, bool) or not isinstance(value, int):
        raise ProtocolError(f"{where}: expected an integer, got {value_repr(value)}")
    return value
