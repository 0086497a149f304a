"""baromap messages as JSON objects: the payload of MCAP JSON channels and of Zenoh samples.

One mapping for both so a floor event looks the same in a recording and on the wire. Every
object carries ``schema`` (this format's version), so a reader can refuse what it does not
understand instead of misreading it. Laser scans are not here: they travel as Foxglove's
standard ``foxglove.LaserScan`` so recordings open in Foxglove without a plugin.

Decoding is untrusted input (a recording from anywhere, a Zenoh peer): msgspec checks every
field's type against the message's dataclass while it parses, in C, so the check costs
nothing next to the parse and whole topics can be decoded at once (:func:`loads_many`).
A float that has no value (NaN, or an infinity) is written as ``null`` and read back as NaN:
``NaN`` is not JSON, and a reader in another language (a dashboard, a Zenoh subscriber in
JavaScript or Rust) would reject the whole object for it. Such payloads, and older ones that
carry a bare ``NaN``, take the slower path that accepts them.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import json
import math
import numbers
import types
import typing
from collections.abc import Mapping, Sequence
from typing import Any

import msgspec

from baromap import messages
from baromap.errors import InputFormatError

SCHEMA_VERSION = 1

#: JSON message types by their schema name (``baromap.<ClassName>``).
JSON_TYPES: dict[str, type] = {
    f"baromap.{cls.__name__}": cls
    for cls in (
        messages.PressureSample,
        messages.Odometry,
        messages.FloorEvent,
        messages.RideEvent,
        messages.FloorState,
        messages.DeviceHealth,
        messages.TruthPose,
        messages.TruthFloor,
    )
}


def schema_name(cls: type) -> str:
    return f"baromap.{cls.__name__}"


@functools.cache
def _field_types(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _base_type(annotation: Any) -> tuple[Any, bool]:
    """(type without None, whether None is allowed)."""
    if isinstance(annotation, types.UnionType) or typing.get_origin(annotation) is typing.Union:
        args = [a for a in typing.get_args(annotation) if a is not type(None)]
        return (args[0] if len(args) == 1 else annotation), True
    return annotation, False


@functools.cache
def field_names(cls: type) -> tuple[str, ...]:
    """A message class's field names, worked out once per class.

    ``dataclasses.fields()`` builds a new tuple from a generator on every call, and CPython
    keeps freed tuples on a free list per size (up to 2000 of each). In the daemon, which
    encodes health reports (6 fields) and floor states (11) several times a second, the free
    lists of those sizes would grow for minutes after start, and its memory with them
    (``bench/soak.py --probe`` shows it in pymalloc's 96- and 128-byte blocks).
    """
    return tuple(f.name for f in dataclasses.fields(cls))


def to_dict(message: Any) -> dict[str, Any]:
    """A message as a JSON-ready dict (enums by value, mappings as objects)."""
    out: dict[str, Any] = {"schema": SCHEMA_VERSION}
    cls: type = type(message)
    for name in field_names(cls):
        value = getattr(message, name)
        if isinstance(value, enum.Enum):
            value = value.value
        elif isinstance(value, Mapping):
            value = dict(value)
        elif isinstance(value, float) and not math.isfinite(value):
            value = None
        out[name] = value
    return out


class _Envelope(msgspec.Struct):
    """What every payload carries besides its message: the format version."""

    schema: int = SCHEMA_VERSION


_ENVELOPE = msgspec.json.Decoder(_Envelope)
_ENVELOPES = msgspec.json.Decoder(list[_Envelope])


@functools.cache
def _decoder(cls: type) -> msgspec.json.Decoder[Any]:
    return msgspec.json.Decoder(cls)


@functools.cache
def _list_decoder(cls: type) -> msgspec.json.Decoder[Any]:
    return msgspec.json.Decoder(list[cls])  # type: ignore[valid-type]


def _check_version(cls: type, version: Any) -> None:
    if not isinstance(version, int) or isinstance(version, bool) or version > SCHEMA_VERSION:
        raise InputFormatError(f"{cls.__name__}: unsupported schema version {version!r}")


def from_dict(cls: type, data: Mapping[str, Any]) -> Any:
    """Rebuild a message, checking every field's type; unknown keys are ignored so newer
    writers stay readable."""
    _check_version(cls, data.get("schema", SCHEMA_VERSION))
    hints = _field_types(cls)
    data = {
        key: math.nan if value is None and _base_type(hints.get(key)) == (float, False) else value
        for key, value in data.items()
    }
    try:
        return msgspec.convert(data, cls)
    except (msgspec.ValidationError, TypeError, ValueError) as exc:
        raise InputFormatError(f"{cls.__name__}: {exc}") from exc


def _encode_other(value: Any) -> Any:
    """What msgspec does not encode by itself: mappings that are not dicts (a health
    report's counters may be any mapping) and numbers of other kinds (numpy scalars)."""
    if isinstance(value, Mapping):
        return dict(value)
    if isinstance(value, numbers.Integral):
        return int(value)
    if isinstance(value, numbers.Real):
        return float(value)
    raise TypeError(f"cannot encode {type(value).__name__} as JSON")


#: One encoder for every payload. msgspec walks a dataclass in C, its fields in order, enums
#: by value, and writes a float without a value (NaN, an infinity) as ``null``: the object
#: :func:`to_dict` describes, without building it. The recorder encodes every pressure
#: sample this way (50 a second), on a thread whose every message finds cold caches: the
#: Python walk of :func:`to_dict` then ``json`` cost it about 7 us more per message of the
#: daemon's whole mix (scans included), so some 20 us per encoded one.
_ENCODER = msgspec.json.Encoder(enc_hook=_encode_other)
_ENVELOPE_START = b'{"schema":%d' % SCHEMA_VERSION


def dumps(message: Any) -> bytes:
    """``message`` (a dataclass) as one JSON object, ``schema`` first: to_dict's, encoded."""
    body = _ENCODER.encode(message)
    if not body.startswith(b"{"):
        raise TypeError(f"cannot encode {type(message).__name__} as a JSON object")
    return _ENVELOPE_START + (b"," + body[1:] if len(body) > 2 else b"}")


def loads(cls: type, payload: bytes | str) -> Any:
    try:
        message = _decoder(cls).decode(payload)
        version = _ENVELOPE.decode(payload).schema
    except (msgspec.ValidationError, msgspec.DecodeError):
        # null for a float without a value, an older bare NaN, or a payload that is wrong:
        # the lenient path accepts the first two and names what is wrong with the third
        return _loads_lenient(cls, payload)
    _check_version(cls, version)
    return message


def loads_many(cls: type, payloads: Sequence[bytes]) -> list[Any]:
    """Decode many payloads of one type in one parse (a topic of a recording)."""
    if not payloads:
        return []
    joined = b"[" + b",".join(payloads) + b"]"
    try:
        messages_ = _list_decoder(cls).decode(joined)
        versions = _ENVELOPES.decode(joined)
    except (msgspec.ValidationError, msgspec.DecodeError):
        # one payload is odd: decode one by one, to accept NaN or to name the bad one
        return [loads(cls, payload) for payload in payloads]
    if len(messages_) != len(payloads):  # a payload that was not one JSON value
        return [loads(cls, payload) for payload in payloads]
    for envelope in versions:
        if envelope.schema > SCHEMA_VERSION:
            _check_version(cls, envelope.schema)
    return list(messages_)


def _loads_lenient(cls: type, payload: bytes | str) -> Any:
    try:
        data = json.loads(payload)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputFormatError(f"{cls.__name__}: not JSON: {exc}") from exc
    if not isinstance(data, dict):
        raise InputFormatError(f"{cls.__name__}: expected a JSON object")
    return from_dict(cls, data)


def _json_type(annotation: Any) -> dict[str, Any]:
    base, nullable = _base_type(annotation)
    if isinstance(base, type) and issubclass(base, enum.Enum):
        spec: dict[str, Any] = {"type": "string", "enum": [m.value for m in base]}
    elif base is bool:
        spec = {"type": "boolean"}
    elif base is int:
        spec = {"type": "integer"}
    elif base is float:
        spec = {"type": "number"}
        nullable = True  # null: no value (NaN)
    elif base is str:
        spec = {"type": "string"}
    elif typing.get_origin(base) in (Mapping, dict) or base in (Mapping, dict):
        spec = {"type": "object", "additionalProperties": {"type": "integer"}}
    else:
        raise TypeError(f"no JSON schema for {annotation!r}")
    if nullable:
        spec["type"] = [spec["type"], "null"]
    return spec


@functools.cache
def json_schema(cls: type) -> bytes:
    """JSON Schema of a message type, as MCAP schema data."""
    hints = _field_types(cls)
    properties = {"schema": {"type": "integer", "const": SCHEMA_VERSION}}
    properties.update({f.name: _json_type(hints[f.name]) for f in dataclasses.fields(cls)})
    required = [
        f.name
        for f in dataclasses.fields(cls)
        if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    ]
    schema = {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": schema_name(cls),
        "description": (cls.__doc__ or "").strip().split("\n\n")[0],
        "type": "object",
        "properties": properties,
        "required": required,
    }
    return json.dumps(schema, indent=1).encode()
