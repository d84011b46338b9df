"""Finding a behaviour by its name and validating its parameters.

A behaviour is named by an import path, ``"mypkg.flock:Flocking"`` (module, colon, class), or
by a name registered in the ``mrswarm.behaviours`` entry-point group of an installed package
(``[project.entry-points."mrswarm.behaviours"] flocking = "mypkg.flock:Flocking"``), or by the
name of a built-in (:data:`BUILTINS`). Errors are :class:`~groundfloor.schema.ConfigError`\\ s
naming the field (``behaviour``, ``params.<field>``), raised when the scenario is loaded, before
any UAV starts, and again (the same checks) in each UAV process.
"""

from __future__ import annotations

import importlib
import re
from typing import Any

import msgspec

from groundfloor.schema import ConfigError, convert
from uav_stack.sdk.behaviour import Behaviour

ENTRY_POINT_GROUP = "mrswarm.behaviours"
# the built-in behaviours of the SDK, by name (uav_stack/sdk/builtins.py)
BUILTINS: dict[str, str] = {
    "goto": "uav_stack.sdk.builtins:GoToGoal",
    "lawnmower": "uav_stack.sdk.builtins:Lawnmower",
    "random": "uav_stack.sdk.builtins:RandomDirection",
    "plume": "uav_stack.sdk.sensing:PlumeSource",
    "wildfire": "uav_stack.sdk.sensing:Wildfire",
}
_PATH = re.compile(r"^[A-Za-z_][\w]*(\.[A-Za-z_][\w]*)*:[A-Za-z_][\w]*(\.[A-Za-z_][\w]*)*$")
_TOPIC = re.compile(r"^[A-Za-z0-9_\-]+(/[A-Za-z0-9_\-]+)*$")
MAX_TOPIC_LEN = 64
SWARM_MAX_MESSAGE_BYTES = 64 * 1024  # swarmnet's limit for a swarm message


def registered() -> dict[str, str]:
    """Every behaviour name known here: the built-ins, then the entry points of installed packages."""
    from importlib import metadata  # only to find a behaviour by name

    out = dict(BUILTINS)
    for ep in metadata.entry_points(group=ENTRY_POINT_GROUP):
        out[ep.name] = ep.value
    return out


def resolve(spec: str, where: str = "behaviour") -> type[Behaviour[Any]]:
    """The behaviour class ``spec`` names (an import path ``module:Class`` or a registered name);
    ConfigError on ``where`` if there is none, or it is not a Behaviour."""
    path = spec
    if ":" not in spec:
        names = registered()
        if spec not in names:
            raise ConfigError(where, f"{spec!r} is neither an import path (package.module:Class) nor a registered "
                                     f"behaviour (registered: {', '.join(sorted(names))})")
        path = names[spec]
    if not _PATH.match(path):
        raise ConfigError(where, f"{path!r} is not an import path: expected package.module:Class")
    module_name, _, attr = path.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise ConfigError(where, f"cannot import {module_name!r} ({exc}); is its package installed, "
                                 "or its folder on PYTHONPATH?") from None
    except Exception as exc:  # noqa: BLE001 - the user's module failed while importing: say how
        raise ConfigError(where, f"importing {module_name!r} failed: {type(exc).__name__}: {exc}") from None
    obj: Any = module
    for part in attr.split("."):
        obj = getattr(obj, part, None)
        if obj is None:
            raise ConfigError(where, f"module {module_name!r} has no {attr!r}")
    if not (isinstance(obj, type) and issubclass(obj, Behaviour)):
        raise ConfigError(where, f"{path} is not a Behaviour subclass (from mrswarm.api import Behaviour)")
    check_class(obj, where)
    return obj


def check_class(cls: type[Behaviour[Any]], where: str = "behaviour") -> None:
    """The class attributes a behaviour declares are usable: its Params a Struct, its topics and
    message types valid, its rate and message size in range."""
    name = cls.__name__
    if not (isinstance(cls.Params, type) and issubclass(cls.Params, msgspec.Struct)):
        raise ConfigError(where, f"{name}.Params must be a msgspec.Struct")
    if not isinstance(cls.messages, dict):
        raise ConfigError(where, f"{name}.messages must be a dict of topic -> msgspec.Struct type")
    for topic, typ in cls.messages.items():
        if not (isinstance(topic, str) and _TOPIC.match(topic) and len(topic) <= MAX_TOPIC_LEN):
            raise ConfigError(where, f"{name}.messages: topic {topic!r}: use up to {MAX_TOPIC_LEN} characters of "
                                     "[A-Za-z0-9_-] separated by '/'")
        if not (isinstance(typ, type) and issubclass(typ, msgspec.Struct)):
            raise ConfigError(where, f"{name}.messages[{topic!r}] must be a msgspec.Struct type")
    if not (isinstance(cls.rate_hz, (int, float)) and 0.0 < cls.rate_hz <= 1000.0):
        raise ConfigError(where, f"{name}.rate_hz must be in (0, 1000] Hz, got {cls.rate_hz!r}")
    if not (isinstance(cls.max_message_bytes, int) and 16 <= cls.max_message_bytes <= SWARM_MAX_MESSAGE_BYTES - 512):
        raise ConfigError(where, f"{name}.max_message_bytes must be in 16..{SWARM_MAX_MESSAGE_BYTES - 512}")
    if not isinstance(cls.avoidance, bool):
        raise ConfigError(where, f"{name}.avoidance must be True or False")
    if cls.step is Behaviour.step:
        raise ConfigError(where, f"{name} has no step(ctx) method")


def validate_params(cls: type[Behaviour[Any]], params: Any, where: str = "params") -> msgspec.Struct:
    """``params`` (a mapping from the scenario) validated into ``cls.Params``; ConfigError naming
    ``where.<field>``. Unknown fields are refused even if the Struct does not forbid them."""
    if params is None:
        params = {}
    if not isinstance(params, dict):
        raise ConfigError(where, f"expected a mapping of {cls.Params.__name__}'s fields, got {type(params).__name__}")
    known = {f.encode_name for f in msgspec.structs.fields(cls.Params)}
    unknown = sorted(str(k) for k in params if k not in known)
    if unknown:
        raise ConfigError(f"{where}.{unknown[0]}", f"unknown field of {cls.__name__}.Params "
                                                   f"(expected one of: {', '.join(sorted(known)) or 'none'})")
    try:
        return convert(params, cls.Params)
    except ConfigError as exc:
        raise ConfigError(f"{where}.{exc.path}" if exc.path else where, exc.msg) from None


def load(spec: str, params: Any, where: str = "") -> tuple[type[Behaviour[Any]], msgspec.Struct]:
    """The behaviour class and its validated parameters; ConfigError naming ``<where>.behaviour``
    or ``<where>.params.<field>``."""
    prefix = f"{where}." if where else ""
    cls = resolve(spec, f"{prefix}behaviour")
    return cls, validate_params(cls, params, f"{prefix}params")


def merged(params: dict[str, Any] | None, override: dict[str, Any] | None) -> dict[str, Any]:
    """A UAV's parameters: the mission's, with its own (``mission.per_uav.<id>.params``) over them, one level deep."""
    out = dict(params or {})
    out.update(override or {})
    return out
