"""Typed configuration: msgspec Structs whose errors name the field.

Every configuration of mrswarm (the scenario file, the config a UAV process reads, the netem
mapping, the discovery options) is a :class:`Config`: a frozen msgspec Struct that refuses
unknown fields, with ranges and units in ``Annotated[..., msgspec.Meta(...)]``. msgspec checks
types and ranges while it decodes; rules between fields go in ``__post_init__`` and raise
:class:`ConfigError` naming the field. :func:`convert` and :func:`decode_json` turn msgspec's
errors (``Expected `float` <= 1.0 - at `$.v2v.loss.p```) into a :class:`ConfigError` whose
``path`` is the dotted field (``v2v.loss.p``) and whose message says what is wrong and what
was given (``must be a probability in [0, 1], got 1.5``; :mod:`groundfloor.schema_errors`,
imported only when something is wrong).

Why msgspec: a swarm runs dozens of UAV processes on one machine, and every MB of a process
counts. msgspec and these modules add about 1.1 MB of RSS to a UAV process (measured on
``scenarios/coverage.yaml``: 58.2 -> 59.3 MB per UAV); pydantic would add about 10 MB.
"""

from __future__ import annotations

from typing import Any, TypeVar

import msgspec

from groundfloor.errors import MrswarmError

T = TypeVar("T")


class Config(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Base of every configuration type: immutable, no unknown fields."""


class ConfigError(ValueError, MrswarmError):
    """An invalid configuration: ``path`` is the dotted field (``""``: the whole thing), ``msg`` what is wrong.

    Raised from ``__post_init__`` with the path below the Struct (``ConfigError("r", "required")``);
    :func:`convert` prefixes where that Struct sits (``v2v.loss.r: required``).
    """

    def __init__(self, path: str, msg: str):
        super().__init__(f"{path}: {msg}" if path else msg)
        self.path = path
        self.msg = msg


def join(*parts: str) -> str:
    """Dotted path of non-empty parts: ``join("network.netem", "v2v.delay")``."""
    return ".".join(p for p in parts if p)


def convert(data: Any, type_: type[T], *, error: type[ConfigError] = ConfigError) -> T:
    """Validate plain data (a YAML or JSON mapping) into ``type_``; raises ``error`` naming the field."""
    try:
        return msgspec.convert(data, type_)
    except msgspec.ValidationError as exc:
        from groundfloor.schema_errors import explain

        raise error(*explain(exc, data, type_)) from None


def decode_json(buf: bytes | str, type_: type[T], *, error: type[ConfigError] = ConfigError) -> T:
    """Decode and validate JSON into ``type_``; raises ``error`` naming the field."""
    try:
        return msgspec.json.decode(buf, type=type_)
    except msgspec.ValidationError as exc:
        from groundfloor.schema_errors import explain

        try:
            data = msgspec.json.decode(buf)
        except msgspec.DecodeError:
            data = None
        raise error(*explain(exc, data, type_)) from None
    except msgspec.DecodeError as exc:
        raise error("", f"not valid JSON: {exc}") from None


def to_builtins(obj: Any) -> Any:
    """Plain dicts, lists and scalars, as JSON would carry them (for YAML, JSON or a merge)."""
    return msgspec.json.decode(msgspec.json.encode(obj))
