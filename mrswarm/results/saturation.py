"""Whether the host kept up: the ``saturated`` list of summary.json, and what makes ``mrswarm run`` exit 4.

A run on a machine that cannot keep up still flies, but its figures measure the machine, not the
swarm: the UAVs' loops run late, and poses queue and are lost. Two signs, from the UAVs' own
counters, say so:

* **late ticks**: more than :data:`LATE_TICKS_MAX` of the UAVs' ticks began more than half a
  period after their time (the counters file's ``loop`` section, uav_stack/runtime.py);
* **poses lost** beyond :data:`POSE_LOSS_MAX` on links no network impairment was configured on
  (a netem profile's losses are the experiment's, not the machine's), and not with spatial
  interest: a far neighbour's sequence numbers have gaps by design (docs/scale.md), so the loss
  counted from them measures the filter, not the machine.
"""

from __future__ import annotations

from typing import Any

LATE_TICKS_MAX = 0.05  # fraction of all UAVs' ticks
POSE_LOSS_MAX = 0.05  # fraction of the poses expected on unimpaired links


def saturation_reasons(pose_loss: float | None, stats: dict[int, dict[str, Any]], interest: bool = False) -> list[str]:
    """Why this run's host could not keep up (empty: it did); ``pose_loss``: the run's fraction of
    neighbours' poses lost (None: not known); ``interest``: the run had spatial interest (its loss
    says nothing of the machine)."""
    out: list[str] = []
    loops = [s["loop"] for s in stats.values() if isinstance(s.get("loop"), dict)]
    ticks = sum(int(lp.get("ticks", 0)) for lp in loops)
    late = sum(int(lp.get("late", 0)) for lp in loops)
    if ticks and late / ticks > LATE_TICKS_MAX:
        worst = max(float(lp.get("worst_late_s", 0.0)) for lp in loops)
        out.append(f"UAV loops ran late: {100 * late / ticks:.1f} % of their ticks began more than half a period late "
                   f"(worst {1000 * worst:.0f} ms); the machine could not keep up: fewer UAVs, pools (fleet.pool) or "
                   "another host (docs/scale.md)")
    impaired = any((lk.get("class") or "unimpaired") != "unimpaired"
                   for s in stats.values() if isinstance(s.get("netem"), dict)
                   for lk in (s["netem"].get("links") or {}).values() if isinstance(lk, dict))
    if pose_loss is not None and not impaired and not interest and pose_loss > POSE_LOSS_MAX:
        out.append(f"{100 * pose_loss:.1f} % of poses lost with no network impairment configured: the machine "
                   "could not keep up")
    return out
