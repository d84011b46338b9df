"""Incidents: a UAV that fell, dropped out of control or hit the ground, found in its recorded trajectory,
and two UAVs closer than the safety distance.

Counted beside collisions (mrswarm/results/analysis.py) and they make ``mrswarm run`` exit with 3
(docs/reliability.md). From each UAV's own records (a virtual UAV records its FCU's ground
truth, so an injected GPS glitch cannot fake or hide one), with these thresholds:

* ``motors_stopped_in_air``: disarmed while higher than :data:`AIRBORNE_Z` (the operator's
  ``kill``, a forced disarm, a failsafe that cuts the motors);
* ``uncontrolled_descent``: sinking faster than :data:`DESCENT_MS` for at least two records in a
  row; nothing the agent or the FCU commands goes down faster than 3 m/s (PX4's fastest
  default descent, MPC_Z_VEL_MAX_DN, is 1.5 m/s; the agent's altitude hold is limited to 2 m/s);
* ``ground_impact``: reaching the ground (lower than :data:`GROUND_Z`) while sinking faster than
  :data:`IMPACT_MS`; a landing touches down at 0.7 m/s;
* ``below_safety_distance``: two airborne UAVs closer than ``flight.safety_distance`` during the
  mission (the distance collision avoidance is there to keep; mrswarm/results/analysis.py finds the
  stretches on its 10 Hz grid, gaps under a second joined): the pair, when, for how long, how close.
"""

from __future__ import annotations

import numpy as np

from mrswarm.records.summary import Incident
from mrswarm.results.run_data import AIRBORNE_Z

GROUND_Z = 0.3  # m above the UAV's ground: on the ground
DESCENT_MS = 4.0  # m/s
IMPACT_MS = 2.0  # m/s


def _onsets(mask: np.ndarray, min_len: int = 1) -> list[int]:
    """Indices where ``mask`` becomes true and stays true for at least ``min_len`` samples."""
    out = []
    k, n = 0, len(mask)
    while k < n:
        if mask[k]:
            j = k
            while j < n and mask[j]:
                j += 1
            if j - k >= min_len:
                out.append(k)
            k = j
        else:
            k += 1
    return out


def find_incidents(uav: int, t: np.ndarray, z: np.ndarray, vz: np.ndarray, armed: np.ndarray, t0: float) -> list[Incident]:
    """Incidents of one UAV from its trajectory (wall time, height above the origin, vertical speed, armed), times
    from ``t0``. Heights are taken above the UAV's own ground: where it stood, disarmed, at its first record (a
    real autopilot's home need not be at the origin's altitude), else the origin."""
    out: list[Incident] = []
    if len(t) < 2:
        return out
    if armed[0] == 0 and np.isfinite(z[0]):
        z = z - z[0]
    for k in _onsets((armed == 0) & (z > AIRBORNE_Z)):
        out.append(Incident(uav=uav, kind="motors_stopped_in_air", t_s=round(float(t[k] - t0), 2), z_m=round(float(z[k]), 2),
                            vz_ms=round(float(vz[k]), 2), detail=f"disarmed {z[k]:.1f} m above the ground"))
    for k in _onsets((vz < -DESCENT_MS) & (z > GROUND_Z), min_len=2):
        out.append(Incident(uav=uav, kind="uncontrolled_descent", t_s=round(float(t[k] - t0), 2), z_m=round(float(z[k]), 2),
                            vz_ms=round(float(vz[k]), 2), detail=f"sinking at {-vz[k]:.1f} m/s (limit {DESCENT_MS:g})"))
    touch = np.nonzero((z[1:] <= GROUND_Z) & (z[:-1] > GROUND_Z))[0] + 1
    for k in (int(i) for i in touch):
        speed = float(min(vz[k - 1], vz[k]))
        if speed < -IMPACT_MS:
            out.append(Incident(uav=uav, kind="ground_impact", t_s=round(float(t[k] - t0), 2), z_m=round(float(z[k - 1]), 2),
                                vz_ms=round(speed, 2), detail=f"hit the ground at {-speed:.1f} m/s (a landing: 0.7 m/s)"))
    return sorted(out, key=lambda i: i.t_s)


def safety_incident(pair: tuple[int, int], t_s: float, duration_s: float, min_m: float, min_at_s: float,
                    safety_m: float) -> Incident:
    """Two UAVs below the safety distance from ``t_s`` (s after the mission start) for ``duration_s``, ``min_m`` apart
    at the closest."""
    return Incident(uav=pair[0], kind="below_safety_distance", t_s=round(t_s, 2), pair=list(pair), min_m=round(min_m, 2),
                    duration_s=round(duration_s, 2), min_at_s=round(min_at_s, 2),
                    detail=f"UAVs {pair[0]} and {pair[1]} {min_m:.2f} m apart at the closest (safety distance {safety_m:g} m), "
                           f"{duration_s:.1f} s below it")
