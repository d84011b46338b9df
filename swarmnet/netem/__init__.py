"""A netem-like shim: per-link delay, jitter, loss, bursts, duplication, reordering, rate, distance.

See docs/netem.md. The pieces:

* :mod:`swarmnet.netem.config`: the configuration schema (msgspec Structs, the same in the
  scenario loader, the CLI and the UAV process), presets and per-link resolution;
* :mod:`swarmnet.netem.models`: delay distributions (AR(1)-correlated), loss models
  (Bernoulli, Gilbert-Elliott, 4-state), distance models, outage schedules;
* :mod:`swarmnet.netem.shim`: :class:`NetemShim`, the per-(sender -> me) links, the single
  time-ordered heap and the statistics;
* :mod:`swarmnet.netem.control`: the runtime control message on ``mrs/<swarm>/netem/set``
  and its codec (a msgspec Struct, decoded and checked in one call).

The names below are imported on first use: a UAV process reads its configuration (which
names :class:`~swarmnet.netem.config.NetemSpec`) without loading the shim and its models,
which only a configured node needs.
"""

from __future__ import annotations

import importlib
from typing import Any

_WHERE = {"CLASSES": "config", "NetemConfig": "config", "NetemConfigError": "config", "NetemSpec": "config",
          "parse_netem": "config", "PRESETS": "presets", "NetemShim": "shim"}

__all__ = sorted(_WHERE)


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        return getattr(importlib.import_module(f"swarmnet.netem.{_WHERE[name]}"), name)
    raise AttributeError(f"module 'swarmnet.netem' has no attribute {name!r}")
