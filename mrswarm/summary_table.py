"""The summary printed at the end of ``mrswarm run`` (and by ``mrswarm results``): a rich table of summary.json."""

from __future__ import annotations

from rich.console import Console
from rich.table import Table

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
    if net := s.network:
        age = net.pose_age_ms
        t.add_row("pose age", f"p50 {_fmt(age.p50)} ms, p99 {_fmt(age.p99)} ms over {age.n} poses")
        t.add_row("messages", f"sent {sum(net.messages_sent.values())}, received {sum(net.messages_received.values())}, "
                              f"rejected {sum(net.messages_rejected.values())}, pose loss {100 * net.pose_loss:.2f} %")
        for cls, c in (net.netem.classes if net.netem else {}).items():  # docs/netem.md
            t.add_row(f"netem {cls}", f"{c.links} links: delay mean {_fmt(c.delay_ms.mean)} ms, p99 "
                                      f"{_fmt(c.delay_ms.p99)} ms, lost {100 * c.loss:.2f} %, reordered {c.reordered}")
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
    if s.plot_error:
        t.add_row("plot failed", s.plot_error)
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


def print_summary(console: Console, s: RunSummary) -> None:
    console.print(summary_table(s))


def _fmt(v: float | int | None) -> str:
    return "-" if v is None else (f"{v:.1f}" if isinstance(v, float) else str(v))
