"""A netem-like shim: per-link delay, jitter, loss, bursts, duplication, reordering, rate, distance.

See docs/netem.md. The pieces:

* :mod:`swarmnet.netem.config`: the configuration schema (plain Python validation, so the UAV
  process validates runtime changes without pydantic), presets and per-link resolution;
* :mod:`swarmnet.netem.models`: delay distributions (AR(1)-correlated), loss models
  (Bernoulli, Gilbert-Elliott, 4-state), distance models, outage schedules;
* :mod:`swarmnet.netem.shim`: :class:`NetemShim`, the per-(sender -> me) links, the single
  time-ordered heap and the statistics;
* :mod:`swarmnet.netem.control`: the runtime control message on ``mrs/<swarm>/netem/set``.
"""

from swarmnet.netem.config import CLASSES, NetemConfig, NetemConfigError, parse_netem
from swarmnet.netem.presets import PRESETS
from swarmnet.netem.shim import NetemShim

__all__ = ["CLASSES", "NetemConfig", "NetemConfigError", "NetemShim", "PRESETS", "parse_netem"]
