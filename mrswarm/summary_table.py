"""The summary printed at the end of ``mrswarm run`` (and by ``mrswarm results``): a rich table of summary.json."""

from __future__ import annotations

from rich import box
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from mrswarm.gcs.session import format_ids
from mrswarm.summary import RunSummary
from mrswarm.world_summary import WorldSummary


def summary_table(s: RunSummary) -> Table:
    t = Table(title=f"summary: {s.scenario}", show_header=False)
    t.add_column(style="bold")
    t.add_column()
    if s.error:
        t.add_row("error", s.error)
    if cov := s.coverage:
        t.add_row("coverage", f"{100 * cov.final:.1f} % (50 % at {_fmt(cov.time_to_50_s)} s, 90 % at {_fmt(cov.time_to_90_s)} s)")
    if e := s.encounter:
        t.add_row("encounter", f"closest {e.separation_m:.2f} m at {e.meeting_point}, from starts {e.distance_from_start_m}")
    if s.goals:
        t.add_row("goals reached", ", ".join(f"UAV {u}: {'yes' if g.reached else 'no'}" for u, g in s.goals.items()))
    if sep := s.separation:
        t.add_row("min separation", f"{_fmt(sep.min_m)} m (safety {sep.safety_distance_m} m)")
        t.add_row("collisions", str(sep.collisions))
    if (rtf := s.rtf) and rtf.mean is not None and rtf.min is not None:
        t.add_row("RTF", f"mean {rtf.mean:.3f}, min {rtf.min:.3f}")
    if to := s.takeoff:
        t.add_row("takeoff", f"acknowledged after {_fmt(to.acked_s)} s ({to.sends} sends), "
                             f"all airborne after {_fmt(to.all_airborne_s)} s")
    if net := s.network:
        age, use = net.transport_age_ms, net.use_age_ms
        worst = f"; worst link p99 {_fmt(lk.p99_max_ms)} ms" if (lk := net.transport_age_links) else ""
        t.add_row("transport age",
                  f"p50 {_fmt(age.p50)} ms, p99 {_fmt(age.p99)} ms, max {_fmt(age.max)} ms over {age.n} poses{worst}")
        t.add_row("age at use", f"p50 {_fmt(use.p50)} ms, p99 {_fmt(use.p99)} ms over {use.n} poses")
        if net.negative_ages:
            t.add_row("negative ages", f"{net.negative_ages} (clocks of two hosts disagree)")
        t.add_row("messages", f"sent {sum(net.messages_sent.values())}, received {sum(net.messages_received.values())}, "
                              f"rejected {sum(net.messages_rejected.values())}, pose loss {100 * net.pose_loss:.2f} %")
        for cls, c in (net.netem.classes if net.netem else {}).items():  # docs/netem.md
            t.add_row(f"netem {cls}", f"{c.links} links: delay mean {_fmt(c.delay_ms.mean)} ms, p99 "
                                      f"{_fmt(c.delay_ms.p99)} ms, lost {100 * c.loss:.2f} %, reordered {c.reordered}")
    if s.incidents:
        t.add_row("incidents", "; ".join(f"UAV {i.uav} {i.kind.replace('_', ' ')} at {i.t_s:.1f} s" for i in s.incidents[:6])
                  + (f" (+{len(s.incidents) - 6} more)" if len(s.incidents) > 6 else ""))
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
        t.add_row("failsafes", ", ".join(f"{k} x{n}" for k, n in sorted(kinds.items())) or "-")
    if rec := s.records:
        t.add_row("records", f"writes failed on UAVs {rec.uavs} ({', '.join(f'{k} x{v}' for k, v in rec.errors.items())}), "
                             f"{rec.rows_dropped} rows lost" + (f"; runner: {', '.join(rec.runner)}" if rec.runner else ""))
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
                      + (", ".join(f"{k} {v}" for k, v in sorted(refused.items())) if any(refused.values()) else "nothing"))
    if w := s.world:
        for row in world_rows(w):
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


def world_rows(w: WorldSummary) -> list[tuple[str, str]]:
    """The world section's lines (docs/world.md)."""
    rows = []
    if p := w.plume:
        rows.append(("source estimate", f"error {_fmt(p.error_final_m)} m at the end (best UAV {_fmt(p.error_best_final_m)} m), "
                                        f"under 5 m from {_fmt(p.below_5m_at_s)} s; {p.uavs_estimating} UAVs estimating"))
    if f := w.fire:
        out = (f"out at {f.extinguished_at_s:.0f} s" if f.extinguished_at_s is not None
               else f"{f.cells_burning_at_end} cells still burning")
        rows.append(("fire", f"burnt {f.burnt_area_m2:.0f} m^2, {f.cells_extinguished} cells put out with "
                             f"{f.sprayed_l:.0f} l; {out}"))
    if z := w.zones:
        rows.append(("no-fly zones", f"{z.entries} entries into {z.zones} zones, closest {_fmt(z.min_clearance_m)} m"))
    if a := w.airspace:
        rows.append(("between swarms", f"closest {_fmt(a.min_separation_m)} m, {a.conflicts} conflicts, "
                                       f"{a.collisions} collisions, {a.cross_swarm_samples} cross-swarm samples "
                                       f"(feed {'on' if a.feed else 'off'})"))
    for name, d in w.sensors.items():
        rows.append((f"sensor {name}", f"{d.received} readings, {_fmt(d.rate_hz_median)} Hz, delay p50 {_fmt(d.delay_ms_p50)} ms "
                                       f"(latency {1000 * d.latency_s:.0f} ms)"))
    if w.service is not None:
        rows.append(("world service", f"CPU {_fmt(w.service.cpu_percent)} % of one core, {w.service.uavs_tracked} UAVs tracked"))
    return rows


def fault_table(s: RunSummary) -> Table:
    """The per-fault table: what was injected when, how soon the swarm noticed, how soon it was back."""
    t = Table(title=f"faults: {s.scenario} (detected, recovered: s after the fault)", box=box.MINIMAL_HEAVY_HEAD,
              title_justify="left", padding=(0, 1), pad_edge=False, show_edge=False, collapse_padding=True)
    for col in ("at s", "fault", "UAVs", "detected", "recovered", "collisions", "coverage lost"):
        t.add_column(col, justify="left" if col in ("fault", "UAVs") else "right", no_wrap=True)
    for f in s.faults:
        t.add_row(_fmt(f.at_s), f.kind + ("" if f.ok else " (failed)"), format_ids(f.targets) if f.targets else "-",
                  _fmt(f.detection_s), _fmt(f.recovery_s), str(f.collisions),
                  "-" if f.coverage_lost is None else f"{100 * f.coverage_lost:.1f} %")
    return t


def print_summary(console: Console, s: RunSummary) -> None:
    console.print(summary_table(s))
    if s.faults:
        console.print(fault_table(s))


def _fmt(v: float | int | None) -> str:
    return "-" if v is None else (f"{v:.1f}" if isinstance(v, float) else str(v))
