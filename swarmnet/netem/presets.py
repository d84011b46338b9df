"""Named netem presets: a profile per link class, with where each number comes from.

Link classes (see :mod:`swarmnet.netem.config`): ``v2v`` virtual <-> virtual UAV, ``v2p``
virtual <-> physical UAV, ``ground`` ground station <-> virtual UAV. On a cellular network a
UAV-to-UAV message crosses the radio twice (uplink to the edge, downlink to the other UAV),
so ``v2v`` models two radio legs; ``v2p`` and ``ground`` model one, because the physical
UAV's own leg is real and the ground station sits on the wired edge. Two legs of a normal
delay ``m +- s`` add up to ``2m +- s*sqrt(2)``; two legs of loss ``L`` to about ``2L``.

Sources (docs/netem.md has the full table). Jitter, loss and outages are our engineering
estimates anchored on the sources named, not measurements: replace them with logs of a
physical UAV when there are some.

* ``5g-campus``: Sende et al. 2024 (the seed paper), 5G Playground Carinthia campus network:
  ping RTT UAV <-> edge server 9.81 ms mean (95 % CI 0.27 ms), independent of the number of
  UAVs; the paper itself adds 9.81 ms as the UAV-to-UAV network delay. So ``v2v`` = 9.81 ms one
  way, one leg = 4.905 ms. Jitter, loss and the NR <-> LTE fallback outages (held 50-150 ms
  about once a minute; intra-LTE handover interruptions are tens of ms, Han et al., IEEE
  Commun. Mag. 53(3), 2015) are estimates for a 5G NSA link.
* ``lte``: low-altitude LTE (below about 60 m): 25 +- 8 ms per leg (3GPP TR 36.777: C2 one-way
  delay <= 50 ms; Zulkifley et al., Sensors 21(8), 2021, measured RTTs up to 94 ms at 170 m),
  0.4 % loss in bursts of 2 per leg, 10 Mbit/s uplink, a handover about every 60 s that holds
  traffic for 30-80 ms.
* ``degraded``: a "bad day": about 100 +- 30 ms and 10 % bursty loss between UAVs (mean burst
  3), 256 kbit/s, a few times the 60-100 kbit/s 3GPP asks for a C2 link (TR 36.777).
* ``wifi-mesh``: a direct air-to-air 5.8 GHz mesh, one hop: 2 +- 1 ms, 20 Mbit/s, GE loss
  p 0.005 r 0.5, and log-distance path loss: exponent 2.8 (Khawaja et al.: 2.54-3.04
  suburban/open UAV links), shadowing 4 dB, 20 dBm, 0 dBi, sensitivity -91 dBm (Mininet-WiFi's
  noise threshold), reference loss 47.72 dB (Friis at 1 m, 5.8 GHz): delivery probability 0.5
  at ~182 m.
* ``lan``: a switched Ethernet LAN, the seed paper's setting for its virtual UAVs: 0.3 +- 0.1 ms.
* ``none``: no impairment at all (every link a pass-through).
"""

from __future__ import annotations

from typing import Any

_HO_5G = {"every_s": 60.0, "duration_ms": [50.0, 150.0], "mode": "hold"}
_HO_LTE = {"every_s": 60.0, "duration_ms": [30.0, 80.0], "mode": "hold"}
_WIFI_DISTANCE = {
    "model": "log_distance", "exponent": 2.8, "sigma_db": 4.0, "freq_ghz": 5.8, "tx_dbm": 20.0, "gains_dbi": 0.0,
    "sensitivity_dbm": -91.0,
}

PRESETS: dict[str, dict[str, Any]] = {
    "none": {"v2v": None, "v2p": None, "ground": None},
    "lan": {
        "v2v": {"delay": {"ms": 0.3, "jitter_ms": 0.1, "distribution": "normal"}},
        "v2p": {"delay": {"ms": 0.3, "jitter_ms": 0.1, "distribution": "normal"}},
        "ground": {"delay": {"ms": 0.3, "jitter_ms": 0.1, "distribution": "normal"}},
    },
    "5g-campus": {
        "v2v": {
            "delay": {"ms": 9.81, "jitter_ms": 2.0, "distribution": "normal", "correlation": 0.5},
            "loss": {"model": "gilbert_elliott", "rate": 0.008, "burst": 2.0},
            "outage": _HO_5G,
        },
        "v2p": {
            "delay": {"ms": 4.905, "jitter_ms": 1.4, "distribution": "normal", "correlation": 0.5},
            "loss": {"model": "gilbert_elliott", "rate": 0.004, "burst": 2.0},
            "outage": _HO_5G,
        },
        "ground": {
            "delay": {"ms": 4.905, "jitter_ms": 1.4, "distribution": "normal", "correlation": 0.5},
            "loss": {"model": "gilbert_elliott", "rate": 0.004, "burst": 2.0},
            "outage": _HO_5G,
        },
    },
    "lte": {
        "v2v": {
            "delay": {"ms": 50.0, "jitter_ms": 11.3, "distribution": "normal", "correlation": 0.5},
            "loss": {"model": "gilbert_elliott", "rate": 0.008, "burst": 2.0},
            "rate": {"kbit": 10000.0},
            "outage": _HO_LTE,
        },
        "v2p": {
            "delay": {"ms": 25.0, "jitter_ms": 8.0, "distribution": "normal", "correlation": 0.5},
            "loss": {"model": "gilbert_elliott", "rate": 0.004, "burst": 2.0},
            "rate": {"kbit": 10000.0},
            "outage": _HO_LTE,
        },
        "ground": {
            "delay": {"ms": 25.0, "jitter_ms": 8.0, "distribution": "normal", "correlation": 0.5},
            "loss": {"model": "gilbert_elliott", "rate": 0.004, "burst": 2.0},
            "outage": _HO_LTE,
        },
    },
    "degraded": {
        "v2v": {
            "delay": {"ms": 100.0, "jitter_ms": 30.0, "distribution": "normal", "correlation": 0.5},
            "loss": {"model": "gilbert_elliott", "rate": 0.10, "burst": 3.0},
            "rate": {"kbit": 256.0},
        },
        "v2p": {
            "delay": {"ms": 50.0, "jitter_ms": 21.0, "distribution": "normal", "correlation": 0.5},
            "loss": {"model": "gilbert_elliott", "rate": 0.05, "burst": 3.0},
            "rate": {"kbit": 256.0},
        },
        "ground": {
            "delay": {"ms": 50.0, "jitter_ms": 21.0, "distribution": "normal", "correlation": 0.5},
            "loss": {"model": "gilbert_elliott", "rate": 0.05, "burst": 3.0},
        },
    },
    "wifi-mesh": {
        "v2v": {
            "delay": {"ms": 2.0, "jitter_ms": 1.0, "distribution": "normal"},
            "loss": {"model": "gilbert_elliott", "p": 0.005, "r": 0.5},
            "rate": {"kbit": 20000.0},
            "distance": _WIFI_DISTANCE,
        },
        "v2p": {
            "delay": {"ms": 2.0, "jitter_ms": 1.0, "distribution": "normal"},
            "loss": {"model": "gilbert_elliott", "p": 0.005, "r": 0.5},
            "rate": {"kbit": 20000.0},
            "distance": _WIFI_DISTANCE,
        },
        "ground": {
            "delay": {"ms": 2.0, "jitter_ms": 1.0, "distribution": "normal"},
            "loss": {"model": "gilbert_elliott", "p": 0.005, "r": 0.5},
        },
    },
}
