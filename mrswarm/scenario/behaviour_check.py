"""A scenario's behaviour mission checked when the scenario is loaded (docs/sdk.md).

The behaviour is imported in the runner and its parameters validated (the mission's, and each
UAV's of ``mission.per_uav``), so a bad import path or parameter is an error naming the field
(``mission.params.speed: ...``) before any UAV starts. ``behaviour`` alone implies ``type: behaviour``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from msgspec.structs import force_setattr

from groundfloor.schema import ConfigError
from uav_stack.sdk import loader

if TYPE_CHECKING:
    from mrswarm.scenario import Mission


def uav_behaviour(mission: Mission, uav: int) -> tuple[str | None, dict[str, Any]]:
    """The behaviour and parameters of one UAV: its own (``per_uav``) if it names another
    behaviour, else the mission's with its own parameters over them."""
    own = mission.per_uav.get(uav)
    if own is not None and own.behaviour:
        return own.behaviour, dict(own.params)
    return mission.behaviour, loader.merged(mission.params, own.params if own is not None else None)


def check_mission(mission: Mission) -> None:
    """Raise ConfigError (path below the mission) for an unusable behaviour mission; set ``type`` to behaviour."""
    if mission.behaviour is not None:
        if mission.type not in ("coverage", "behaviour"):  # coverage: the default, left as it is
            raise ConfigError("type", f"a mission with a behaviour is of type behaviour, not {mission.type!r}")
        force_setattr(mission, "type", "behaviour")
    elif mission.type == "behaviour":
        raise ConfigError("behaviour", "a behaviour mission needs its behaviour: package.module:Class or a registered name")
    else:
        for name, value in (("params", mission.params), ("per_uav", mission.per_uav)):
            if value:
                raise ConfigError(name, "only for a behaviour mission (give mission.behaviour)")
        return
    loader.load(mission.behaviour, mission.params)
    for uav in sorted(mission.per_uav):
        spec, params = uav_behaviour(mission, uav)
        assert spec is not None
        loader.load(spec, params, f"per_uav.{uav}")


def check_per_uav(mission: Mission, ids: set[int]) -> None:
    """Every UAV of ``mission.per_uav`` is one of the swarm's (``ids``)."""
    extra = sorted(set(mission.per_uav) - ids)
    if extra:
        raise ConfigError(f"mission.per_uav.{extra[0]}", f"no UAV {extra[0]} in the swarm (its UAVs: "
                                                         f"{', '.join(map(str, sorted(ids)))})")
