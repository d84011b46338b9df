"""The SDK behaviours' part of summary.json (docs/sdk.md): their incidents, faults and messages.

From each UAV's stats file (its ``behaviour`` section, :mod:`uav_stack.sdk.adapter`): a
behaviour that was stopped after repeated faults is an incident (``behaviour_stopped``: the UAV
held, then landed); the faults, steps and per-topic message counters are summed over the UAVs.
"""

from __future__ import annotations

from typing import Any

from mrswarm.records.summary import BehaviourSummary, Incident

_TOPIC_SUMS = ("sent", "send_errors", "received", "rejected", "dropped")


def _sections(stats: dict[int, dict[str, Any]]) -> list[tuple[int, dict[str, Any]]]:
    return [(uav, s["behaviour"]) for uav, s in sorted(stats.items()) if isinstance(s.get("behaviour"), dict)]


def behaviour_incidents(stats: dict[int, dict[str, Any]], t0: float) -> list[Incident]:
    """Every behaviour stopped by its guard, as an incident at its time (s after ``t0``, the mission start)."""
    out: list[Incident] = []
    for uav, b in _sections(stats):
        for e in b.get("incidents") or []:
            try:
                out.append(Incident(uav=uav, kind=str(e["kind"]), t_s=round(float(e["t"]) - t0, 2),
                                    detail=str(e.get("detail", ""))[:300]))
            except (KeyError, TypeError, ValueError):
                continue
    return out


def pool_agent_incidents(stats: dict[int, dict[str, Any]], t0: float) -> list[Incident]:
    """A pooled UAV whose agent raised (the pool logged it and flew on), as an incident at its first
    exception (s after ``t0``): ``agent_error``, with how often and the first exception."""
    out: list[Incident] = []
    for uav, s in sorted(stats.items()):
        p = s.get("pool")
        if not isinstance(p, dict) or not p.get("agent_errors"):
            continue
        got = p.get("first_error")
        first: dict[str, Any] = got if isinstance(got, dict) else {}
        try:
            t_s = round(float(first["t"]) - t0, 2)
        except (KeyError, TypeError, ValueError):
            t_s = 0.0
        out.append(Incident(uav=uav, kind="agent_error", t_s=t_s,
                            detail=f"its agent raised {p['agent_errors']} times in its pool (first, in "
                                   f"{first.get('what', '?')}: {str(first.get('error', '?'))[:200]}); the pool flew on"))
    return out


def behaviour_summary(stats: dict[int, dict[str, Any]]) -> BehaviourSummary | None:
    """Faults, steps and messages per topic summed over the UAVs; None if no UAV flew an SDK behaviour."""
    sections = _sections(stats)
    if not sections:
        return None
    faults: dict[str, int] = {}
    topics: dict[str, dict[str, Any]] = {}
    steps = 0
    step_max = 0.0
    stopped: list[int] = []
    names = set()
    for uav, b in sections:
        names.add(str(b.get("behaviour", "")))
        steps += int(b.get("steps") or 0)
        step_max = max(step_max, float((b.get("step_ms") or {}).get("max") or 0.0))
        for k, v in (b.get("faults") or {}).items():
            faults[str(k)] = faults.get(str(k), 0) + int(v)
        if b.get("state") in ("holding", "landing") and b.get("incidents"):
            stopped.append(uav)
        for topic, c in (b.get("topics") or {}).items():
            t = topics.setdefault(str(topic), {k: 0 for k in _TOPIC_SUMS} | {"age_max_ms": None, "_age_sum": 0.0})
            for k in _TOPIC_SUMS:
                t[k] += int(c.get(k) or 0)
            if c.get("age_mean_ms") is not None:
                t["_age_sum"] += float(c["age_mean_ms"]) * int(c.get("received") or 0)
            if c.get("age_max_ms") is not None:
                t["age_max_ms"] = max(float(c["age_max_ms"]), t["age_max_ms"] or 0.0)
    for t in topics.values():
        age_sum = t.pop("_age_sum")
        t["age_mean_ms"] = round(age_sum / t["received"], 2) if t["received"] else None
    return BehaviourSummary(behaviours=sorted(names), uavs=len(sections), steps=steps, step_max_ms=round(step_max, 3),
                            faults=faults, stopped=stopped, topics=topics)


def behaviour_line(b: BehaviourSummary) -> str:
    """The printed summary's line: the behaviours, their faults, the UAVs stopped, the messages per topic."""
    faults = sum(b.faults.values())
    parts = [f"{', '.join(b.behaviours)} on {b.uavs} UAVs, {b.steps} steps (longest {b.step_max_ms:.1f} ms)",
             "no fault" if not faults else ", ".join(f"{n} {k.replace('_', ' ')}" for k, n in sorted(b.faults.items()) if n)]
    if b.stopped:
        parts.append(f"stopped on UAV{'s' if len(b.stopped) > 1 else ''} {', '.join(map(str, b.stopped))} (held, then landed)")
    for topic, c in sorted(b.topics.items())[:4]:
        age = f", age mean {c['age_mean_ms']:.0f} ms" if c.get("age_mean_ms") is not None else ""
        parts.append(f"{topic}: sent {c['sent']}, received {c['received']}, rejected {c['rejected']}{age}")
    return "; ".join(parts)
