"""The summary printed at the end of ``mrswarm run`` (and by ``mrswarm results``): a rich table of summary.json."""

from __future__ import annotations

from msgspec import UNSET
from rich import box
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from mrswarm.records.summary import Incident, RunSummary
from mrswarm.records.world_summary import WorldSummary
from mrswarm.results.wording import format_ids, id_list, metres, plural


def _reach(t: float | None, duration: float | None) -> str:
    return f"at {t:.1f} s" if t is not None else "not reached" + (f" in {duration:.0f} s" if duration else "")


def _separation_rows(s: RunSummary) -> list[tuple[str, str]]:
    sep = s.separation
    if not sep:
        return []
    if sep.min_m is None:
        closest = "never two UAVs airborne at once"
    else:
        closest = metres(sep.min_m) + (f" (UAVs {sep.min_pair[0]} and {sep.min_pair[1]}" if sep.min_pair else " (")
        closest += f" at {sep.min_at_s:.1f} s)" if sep.min_at_s is not None else ")"
    below = sep.time_below_safety_s
    closest += (f"; {below:.1f} s below the {sep.safety_distance_m:g} m safety distance" if below > 0
                else f"; never below the {sep.safety_distance_m:g} m safety distance")
    return [("min separation", closest),
            ("collisions", f"{sep.collisions} (closer than {sep.collision_distance_m:g} m)"
             + (": " + ", ".join(f"UAVs {c.pair[0]} and {c.pair[1]} {plural(c.onsets, 'time')}, {c.min:.1f} m"
                                 for c in sep.collision_pairs[:6]) if sep.collision_pairs else ""))]


def _incident(i: Incident) -> str:
    if i.kind == "below_safety_distance" and i.pair and i.min_m is not UNSET and i.duration_s is not UNSET:
        return f"UAVs {i.pair[0]} and {i.pair[1]} below the safety distance at {i.t_s:.1f} s for {i.duration_s:.1f} s " \
               f"(closest {metres(i.min_m)})"
    return f"UAV {i.uav} {i.kind.replace('_', ' ')} at {i.t_s:.1f} s"


def summary_table(s: RunSummary) -> Table:
    t = Table(title=f"summary: {s.scenario}", show_header=False)
    t.add_column(style="bold")
    t.add_column()
    duration = s.duration_s or None
    if s.error:
        t.add_row("error", s.error)
    if cov := s.coverage:
        t.add_row("coverage", f"{100 * cov.final:.1f} % (50 % {_reach(cov.time_to_50_s, duration)}, "
                              f"90 % {_reach(cov.time_to_90_s, duration)})")
    if e := s.encounter:
        starts = ", ".join(f"{d:.1f} m from UAV {u}'s start" for u, d in e.distance_from_start_m.items())
        t.add_row("encounter", f"closest {e.separation_m:.2f} m at {e.meeting_point[0]:.1f} m east, {e.meeting_point[1]:.1f} m "
                               f"north; {starts}")
    if s.goals:
        t.add_row("goals reached", ", ".join(f"UAV {u}: {'yes' if g.reached else 'no'}" for u, g in s.goals.items()))
    for row in _separation_rows(s):
        t.add_row(*row)
    if s.behaviour:  # SDK behaviours (docs/sdk.md)
        from mrswarm.results.behaviour_report import behaviour_line

        t.add_row("behaviour", behaviour_line(s.behaviour))
    if (rtf := s.rtf) and rtf.mean is not None and rtf.min is not None:
        t.add_row("RTF", f"mean {rtf.mean:.3f}, min {rtf.min:.3f}")
    if to := s.takeoff:
        acked = (f"acknowledged after {to.acked_s:.1f} s" if to.acked_s is not None else "not acknowledged by every UAV")
        up = (f"all airborne after {to.all_airborne_s:.1f} s" if to.all_airborne_s is not None
              else "not every UAV reached its altitude")
        late = (f"; late, the run went on without them: {', '.join(f'UAV {u} ({st})' for u, st in to.late.items())}"
                if to.late else "")
        t.add_row("takeoff", f"{acked} ({plural(to.sends, 'send')}), {up}{late}")
    if net := s.network:
        age, use = net.transport_age_ms, net.use_age_ms
        worst = f"; worst link p99 {_ms(lk.p99_max_ms)}" if (lk := net.transport_age_links) and lk.p99_max_ms is not None else ""
        t.add_row("transport age", f"p50 {_ms(age.p50)}, p99 {_ms(age.p99)}, max {_ms(age.max)} "
                                   f"over {plural(age.n, 'pose')}{worst}" if age.n else "no pose received")
        t.add_row("age at use", f"p50 {_ms(use.p50)}, p99 {_ms(use.p99)} over {plural(use.n, 'pose')}" if use.n
                  else "no pose used")
        if net.negative_ages:
            t.add_row("negative ages", ", ".join(f"{k} {n}" for k, n in sorted(net.negative_ages.items()))
                      + " (clocks of two hosts disagree)")
        t.add_row("messages", f"sent {sum(net.messages_sent.values())}, received {sum(net.messages_received.values())}, "
                              f"rejected {sum(net.messages_rejected.values())}, pose loss {100 * net.pose_loss:.2f} %")
        for cls, c in (net.netem.classes if net.netem else {}).items():  # docs/netem.md
            t.add_row(f"netem {cls}", f"{plural(c.links, 'link')}: delay mean {_ms(c.delay_ms.mean)}, p99 "
                                      f"{_ms(c.delay_ms.p99)}, lost {100 * c.loss:.2f} %, reordered {c.reordered}")
    if s.incidents:
        t.add_row("incidents", "; ".join(_incident(i) for i in s.incidents[:6])
                  + (f" (and {len(s.incidents) - 6} more)" if len(s.incidents) > 6 else ""))
    if s.lost_uavs:
        t.add_row("lost UAVs", "; ".join(
            f"UAV {lu.uav} at {lu.t_s:.1f} s ({lu.signal or f'exit {lu.exit_code}'}"
            + (f": {escape(lu.error[:120])}" if lu.error else "") + ")"
            + (f", back at {lu.restarted_s:.1f} s" if lu.restarted_s is not None else "") for lu in s.lost_uavs))
    if s.stalls:
        t.add_row("stalled UAVs", "; ".join(f"UAV {st.uav} at {st.from_s:.1f} s for {st.duration_s:.1f} s" for st in s.stalls[:6])
                  + (f" (+{len(s.stalls) - 6} more)" if len(s.stalls) > 6 else ""))
    if s.services:
        t.add_row("service outages", "; ".join(
            f"{o.name} down at {o.down_s:.1f} s"
            + (f", back at {o.restarted_s:.1f} s" if o.restarted_s is not None else ", not back")
            for o in s.services))
    if s.failsafes:
        kinds: dict[str, int] = {}
        for fe in s.failsafes:
            if fe.event == "triggered":
                kinds[fe.failsafe] = kinds.get(fe.failsafe, 0) + 1
        t.add_row("failsafes", ", ".join(f"{k.replace('_', ' ')} {plural(n, 'time')}" for k, n in sorted(kinds.items()))
                  or "none triggered (warnings only)")
    if rec := s.records:
        t.add_row("records", f"writes failed on {id_list(rec.uavs)} ("
                             + ", ".join(f"{k} {plural(v, 'time')}" for k, v in rec.errors.items()) + "), "
                             f"{plural(rec.rows_dropped, 'row')} lost"
                             + (f"; runner: {', '.join(rec.runner)}" if rec.runner else ""))
    if s.saturated:
        t.add_row("host", "[yellow]saturated: " + escape("; ".join(s.saturated)) + "[/]")
    if s.degraded:
        t.add_row("degraded", "[yellow]" + escape("; ".join(s.degraded[:4]))
                  + (f" (+{len(s.degraded) - 4} more)" if len(s.degraded) > 4 else "") + "[/]")
    if sec := s.security:
        if sec.mode == "off":
            t.add_row("security", "[yellow]off: plain TCP, no access control[/]")
        else:
            refused = {k: sec.refused_by_uavs.get(k, 0) + sec.refused_by_router.get(k, 0)
                       for k in {*sec.refused_by_uavs, *sec.refused_by_router}}
            t.add_row("security", "mutual TLS, access control; refused: "
                      + (", ".join(f"{k.replace('_', ' ')} {v}" for k, v in sorted(refused.items())) if any(refused.values())
                         else "nothing"))
    if mav := s.mavlink:
        t.add_row("MAVLink", mavlink_row(mav.mode, mav.refused, mav.accepted))
    if w := s.world:
        for row in world_rows(w, duration):
            t.add_row(*row)
    t.add_row("results", f"{s.run_dir}/summary.json" + (f", {s.plot}" if s.plot else ""))
    if s.write_error:
        t.add_row("not written", s.write_error)
    if s.plot_error:
        t.add_row("plot failed", s.plot_error)
    if s.stop_signals:
        t.add_row("stopped by", ", ".join(s.stop_signals))
    if s.runner_lost:
        at = f" after {s.interrupted_at_s:.1f} s of mission" if s.interrupted_at_s else ""
        t.add_row("interrupted", f"[yellow]the runner died{at}[/] (run.json has no end): rebuilt from what was recorded")
    if s.aborted:
        t.add_row("aborted", s.aborted)
    return t


def mavlink_row(mode: str, refused: dict[str, int], accepted: dict[str, int]) -> str:
    """What the UAVs' MAVLink routers accepted from ground stations, in one line."""
    if mode == "off":
        return "no routers (gcs.mavlink: false)"
    said = {"signed": "commands only when signed with the key", "telemetry-only": "[yellow]telemetry only: no signing key[/]",
            "unsigned-allowed": "[yellow]unsigned commands accepted (gcs.allow_unsigned)[/]"}.get(mode, escape(mode))
    nonzero = ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in refused.items() if v)
    routed = accepted.get("to_fcu", 0)
    return f"{said}; {plural(routed, 'frame')} to the FCUs; refused: {nonzero or 'nothing'}"


def world_rows(w: WorldSummary, duration: float | None = None) -> list[tuple[str, str]]:
    """The world section's lines (docs/world.md)."""
    rows = []
    if p := w.plume:
        if p.error_final_m is None:
            rows.append(("source estimate", "no UAV estimated the source"))
        else:
            best = f" (best UAV {p.error_best_final_m:.1f} m)" if p.error_best_final_m is not None else ""
            under = (f"under 5 m from {p.below_5m_at_s:.1f} s" if p.below_5m_at_s is not None
                     else "never under 5 m" + (f" in {duration:.0f} s" if duration else ""))
            rows.append(("source estimate", f"error {p.error_final_m:.1f} m at the end{best}, {under}; "
                                            f"{plural(p.uavs_estimating, 'UAV')} estimating"))
    if f := w.fire:
        out = (f"out at {f.extinguished_at_s:.0f} s" if f.extinguished_at_s is not None
               else f"{plural(f.cells_burning_at_end, 'cell')} still burning")
        rows.append(("fire", f"burnt {f.burnt_area_m2:.0f} m², {plural(f.cells_extinguished, 'cell')} put out with "
                             f"{f.sprayed_l:.0f} l; {out}"))
    if z := w.zones:
        clear = (f"closest {z.min_clearance_m:.1f} m from an edge" if z.min_clearance_m is not None
                 else "no UAV airborne near one")
        inside = (f"{id_list(z.uavs_entering)} inside for {plural(z.entries, 'sample')} (10 Hz)" if z.entries
                  else "no UAV entered")
        rows.append(("no-fly zones", f"{plural(z.zones, 'zone')}: {inside}, {clear}"))
    if a := w.airspace:
        closest = f"closest {a.min_separation_m:.1f} m" if a.min_separation_m is not None else "never airborne together"
        crossed = ("no pose crossed between the swarms" if a.cross_swarm_samples == 0
                   else f"[red]{plural(a.cross_swarm_samples, 'pose')} crossed between the swarms[/]")
        feed = (f"airspace feed on ({plural(a.traffic_messages, 'traffic message')} received)" if a.feed
                else "airspace feed off")
        rows.append(("between swarms", f"{closest}, {plural(a.conflicts, 'conflict')}, {plural(a.collisions, 'collision')}; "
                                       f"{crossed}; {feed}"))
    for name, d in w.sensors.items():
        rate = f", {d.rate_hz_median:.1f} Hz" if d.rate_hz_median is not None else ""
        delay = (f"delay p50 {d.delay_ms_p50:.0f} ms" if d.delay_ms_p50 is not None else "delay not measured")
        wait = f", then {d.wait_ms_p50:.0f} ms to the UAV's next control tick (p50)" if d.wait_ms_p50 is not None else ""
        tick = f", plus up to one {d.world_tick_ms:g} ms world tick and the transport" if d.world_tick_ms is not None else ""
        rows.append((f"sensor {name}", f"{plural(d.received, 'reading')}{rate}, {delay} (configured latency "
                                       f"{1000 * d.latency_s:.0f} ms{tick}){wait}"))
    if w.service is not None:
        cpu = f"CPU {w.service.cpu_percent:.1f} % of one core" if w.service.cpu_percent is not None else "CPU not measured"
        rows.append(("world service", f"{cpu}, {plural(w.service.uavs_tracked, 'UAV')} tracked"))
    return rows


def fault_table(s: RunSummary) -> Table:
    """The per-fault table: what was injected when, how soon the swarm noticed, how soon it was back."""
    t = Table(title=f"faults: {s.scenario} (detected, recovered: s after the fault)", box=box.MINIMAL_HEAVY_HEAD,
              title_justify="left", padding=(0, 1), pad_edge=False, show_edge=False, collapse_padding=True)
    for col in ("at s", "fault", "UAVs", "detected", "recovered", "collisions", "coverage lost"):
        t.add_column(col, justify="left" if col in ("fault", "UAVs") else "right", no_wrap=True)
    for f in s.faults:
        t.add_row(f"{f.at_s:.1f}", f.kind + ("" if f.ok else " (failed)"), format_ids(f.targets) if f.targets else "none",
                  _fmt(f.detection_s, "not seen"), _fmt(f.recovery_s, "not back"), str(f.collisions),
                  "not coverage" if f.coverage_lost is None else f"{100 * f.coverage_lost:.1f} %")
    return t


def print_summary(console: Console, s: RunSummary) -> None:
    console.print(summary_table(s))
    if s.faults:
        console.print(fault_table(s))


def _fmt(v: float | int | None, missing: str) -> str:
    return missing if v is None else (f"{v:.1f}" if isinstance(v, float) else str(v))


def _ms(v: float | None) -> str:
    return "not measured" if v is None else f"{v:.1f} ms"
