"""Turning msgspec's validation errors into ``(dotted path, message)`` (see :mod:`groundfloor.schema`).

msgspec reports ``Expected `float` <= 1.0 - at `$.v2v.loss.p```; users should read
``v2v.loss.p: must be a probability in [0, 1], got 1.5``. Following the path through the
type that was decoded and the data that was given adds what msgspec leaves out: the value,
the choices of a ``Literal``, the whole range and its unit (from ``Meta``), the fields a
Struct does accept, and the key of a mapping where msgspec writes ``[...]``.
"""

from __future__ import annotations

import re
import types
import typing
from typing import Annotated, Any

import msgspec

from groundfloor.schema import ConfigError, join

_AT = re.compile(r"^(?P<msg>.*?) - at `(?P<key>key` in `)?(?P<path>\$[^`]*)`$", re.S)
_SEG = re.compile(r"\.([^.\[]+)|\[(\d+|\.\.\.)\]")
_KINDS = {"float": "a number", "int": "an integer", "str": "a string", "bool": "true or false", "object": "a mapping",
          "array": "a list", "null": "null"}
_MISSING = object()


def explain(exc: msgspec.ValidationError, data: Any = _MISSING, type_: Any = None) -> tuple[str, str]:
    """``(dotted path, message)`` of a msgspec validation error.

    ``data`` (what was decoded) and ``type_`` (what it was decoded into) make the message
    better: the value that was given, the choices of a ``Literal``, and the name of a mapping's
    key where msgspec writes ``[...]``.
    """
    text = str(exc)
    m = _AT.match(text)
    msg, segs, is_key = (m["msg"], _segments(m["path"]), bool(m["key"])) if m else (text, [], False)
    segs, tp, value = _walk(type_, data, segs)
    cause = exc.__cause__
    if isinstance(cause, ConfigError):  # a rule in __post_init__: its own path below this Struct
        return join(".".join(segs), cause.path), cause.msg
    if is_key:
        return ".".join(segs), f"keys must be strings: {msg}"
    if (f := re.match(r"Object contains unknown field `(.+)`$", msg)) is not None:
        names = _field_names(tp)
        hint = f" (expected one of: {', '.join(names)})" if names else ""
        return join(".".join(segs), f[1]), f"unknown field{hint}"
    if (f := re.match(r"Object missing required field `(.+)`$", msg)) is not None:
        tags = [s.__struct_config__.tag for s in _structs(tp) if s.__struct_config__.tag_field == f[1]]
        return join(".".join(segs), f[1]), f"required: one of {', '.join(map(str, tags))}" if tags else "required"
    if re.match(r"Invalid (enum )?value ", msg):
        choices = _choices(tp)
        what = f"must be one of {', '.join(map(str, choices))}" if choices else "is not a valid choice"
        return ".".join(segs), f"{what}, got {_short(value)}" if value is not _MISSING else what
    if (f := re.match(r"Expected `([^`]+)`(.*?)(, got .*)?$", msg)) is not None:
        kinds = " or ".join(_KINDS.get(k.strip(), k.strip()) for k in f[1].split("|"))
        rule = re.sub(r"-?\d+\.\d+(e[+-]?\d+)?", lambda n: f"{float(n[0]):g}", f[2])
        rule = rule.replace(" matching regex", " matching")
        meta = _meta(tp, f[1])
        if meta is not None and re.match(r" [<>]", rule):  # a range: state the whole of it, and the unit
            lo = f"[{_num(meta.ge)}" if meta.ge is not None else f"({_num(meta.gt)}" if meta.gt is not None else None
            hi = f"{_num(meta.le)}]" if meta.le is not None else f"{_num(meta.lt)})" if meta.lt is not None else None
            if lo is not None and hi is not None:
                rule = f" in {lo}, {hi}"
            what = meta.description or ""
            if what == "probability":
                kinds, what = "a probability", ""
            rule += f" ({what})" if what else ""
        got = f", got {_short(value)}" if value is not _MISSING else ""
        return ".".join(segs), f"must be {kinds}{rule}{got}"
    return ".".join(segs), msg[:1].lower() + msg[1:]


def _segments(path: str) -> list[str]:
    return [a or b for a, b in _SEG.findall(path[1:])]


def _num(x: float) -> str:
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e16 else f"{x:g}"


def _short(value: Any) -> str:
    r = repr(value)
    return r if len(r) <= 60 else r[:57] + "..."


def _strip(tp: Any) -> Any:
    while typing.get_origin(tp) is Annotated:
        tp = typing.get_args(tp)[0]
    return tp


def _members(tp: Any) -> list[Any]:
    """The alternatives of a union (Annotated stripped), or ``[tp]``."""
    tp = _strip(tp)
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        return [m for a in typing.get_args(tp) for m in _members(a)]
    return [tp]


def _structs(tp: Any) -> list[type[msgspec.Struct]]:
    return [m for m in _members(tp) if isinstance(m, type) and issubclass(m, msgspec.Struct)]


def _field_names(tp: Any) -> list[str]:
    return sorted({f.encode_name for s in _structs(tp) for f in msgspec.structs.fields(s)})


def _meta(tp: Any, kind: str) -> msgspec.Meta | None:
    """The constraints (``Annotated[..., Meta]``) on the alternative of ``tp`` msgspec names ``kind``."""
    for a in typing.get_args(tp) if typing.get_origin(tp) in (typing.Union, types.UnionType) else (tp,):
        if typing.get_origin(a) is Annotated:
            base, *extra = typing.get_args(a)
            if getattr(base, "__name__", "") == kind:
                return next((m for m in extra if isinstance(m, msgspec.Meta)), None)
    return None


def _choices(tp: Any) -> list[Any]:
    return [v for m in _members(tp) if typing.get_origin(m) is typing.Literal for v in typing.get_args(m)]


def _walk(tp: Any, data: Any, segs: list[str]) -> tuple[list[str], Any, Any]:
    """Follow ``segs`` through the type and the data: (segments with mapping keys filled in, type, value)."""
    out: list[str] = []
    for seg in segs:
        tp, data, name = _step(tp, data, seg)
        out.append(name)
    return out, tp, data


def _step(tp: Any, data: Any, seg: str) -> tuple[Any, Any, str]:
    child: Any = None
    if seg == "...":  # a mapping's value: find the key whose value does not validate
        for m in _members(tp):
            if typing.get_origin(m) is dict and isinstance(data, dict):
                vt = typing.get_args(m)[1]
                for k, v in data.items():
                    try:
                        msgspec.convert(v, vt)
                    except msgspec.ValidationError:
                        return vt, v, str(k)
        return None, _MISSING, "<key>"
    if seg.isdigit():
        i = int(seg)
        for m in _members(tp):
            args = typing.get_args(m)
            if typing.get_origin(m) in (list, tuple) and args:
                child = args[0] if (len(args) == 2 and args[1] is Ellipsis) or typing.get_origin(m) is list else \
                    (args[i] if i < len(args) else None)
                break
        value = data[i] if isinstance(data, (list, tuple)) and i < len(data) else _MISSING
        return child, value, seg
    structs = _structs(tp)
    tag = data.get(structs[0].__struct_config__.tag_field) if structs and isinstance(data, dict) and \
        structs[0].__struct_config__.tag_field else None
    for s in structs:
        cfg = s.__struct_config__
        if cfg.tag_field == seg:  # a tagged union's tag: the choices are the tags
            child = typing.Literal[tuple(x.__struct_config__.tag for x in structs)]
            break
        if tag is not None and cfg.tag != tag:
            continue
        hints = typing.get_type_hints(s, include_extras=True)
        f = next((f for f in msgspec.structs.fields(s) if f.encode_name == seg), None)
        if f is not None:
            child = hints.get(f.name, f.type)
            break
    value = data.get(seg, _MISSING) if isinstance(data, dict) else _MISSING
    return child, value, seg
