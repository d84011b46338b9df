"""``mrswarm run``: launch a scenario, fly it with a live display, stop cleanly, summarise.

Sequence: start the network (rendezvous router) and one process per virtual UAV -> wait
until every agent reports ``ready`` -> command ``takeoff`` -> wait until all hover ->
command ``start`` (the mission clock starts here, for every UAV at once) -> fly for
``duration`` -> stop every process -> analyse the recorded run (summary.json + PNG).
Ctrl-C at any point still stops every process and analyses what was recorded.
"""

from __future__ import annotations

import json
import math
import signal
import time
from dataclasses import dataclass, field
from pathlib import Path
from collections.abc import Callable
from types import FrameType
from typing import Any

import numpy as np
import yaml
from rich.console import Console, Group
from rich.live import Live
from rich.panel import Panel
from rich.progress_bar import ProgressBar
from rich.table import Table

from deploy.runtimes import make_runtime
from mrswarm.results import summarise_run
from mrswarm.scenario import Scenario
from swarmnet.observer import SwarmObserver
from uav_stack.config import NetworkConfig
from uav_stack.runtime import make_connectivity

READY_TIMEOUT_BASE = 30.0
READY_TIMEOUT_PER_UAV = 0.6
TAKEOFF_MARGIN = 30.0


class RunAborted(RuntimeError):
    pass


@dataclass
class LiveMetrics:
    """Coverage and separation estimated live from the poses the observer receives."""

    scenario: Scenario
    covered: np.ndarray | None = None
    cells: np.ndarray | None = None
    rtfs: dict[int, float] = field(default_factory=dict)
    min_sep: float = math.inf
    min_sep_now: float = math.inf

    def __post_init__(self) -> None:
        m = self.scenario.mission
        if m.type == "coverage" and m.area is not None:
            x0, x1, y0, y1 = m.area.as_tuple()
            c = max(m.sensor_radius / 2.0, 0.5)
            xs, ys = np.arange(x0 + c / 2, x1, c), np.arange(y0 + c / 2, y1, c)
            gx, gy = np.meshgrid(xs, ys)
            self.cells = np.stack([gx.ravel(), gy.ravel()], axis=1)
            self.covered = np.zeros(len(self.cells), dtype=bool)

    def add_poses(self, obs: SwarmObserver, fresh: list[Any]) -> None:
        if self.cells is None or not fresh:
            return
        r2 = self.scenario.mission.sensor_radius ** 2
        pts = [(p.x, p.y) for p in fresh if (v := obs.uavs.get(p.uav)) and v.state and v.state.phase in ("mission", "done")]
        if pts:
            a = np.array(pts)
            d2 = ((self.cells[:, None, :] - a[None, :, :]) ** 2).sum(axis=2).min(axis=1)
            self.covered |= d2 <= r2

    def update_separation(self, obs: SwarmObserver) -> None:
        p = np.array([[v.pose.x, v.pose.y, v.pose.z] for v in obs.uavs.values() if v.pose is not None and v.pose.z > 1.0])
        if len(p) >= 2:
            d = np.linalg.norm(p[:, None, :] - p[None, :, :], axis=2)
            d[np.diag_indices(len(p))] = np.inf
            self.min_sep_now = float(d.min())
            self.min_sep = min(self.min_sep, self.min_sep_now)

    @property
    def coverage(self) -> float | None:
        return float(self.covered.mean()) if self.covered is not None else None


class Experiment:
    def __init__(self, scenario: Scenario, out_root: Path = Path("results"), console: Console | None = None,
                 live: bool = True, log_level: str = "INFO", probe: Callable[[Experiment, float], None] | None = None):
        self.scn = scenario
        self.console = console or Console()
        self.live = live and self.console.is_terminal
        stamp = time.strftime("%Y%m%d-%H%M%S")
        self.run_dir = out_root / f"{scenario.name}-{stamp}"
        n = 1
        while self.run_dir.exists():
            n += 1
            self.run_dir = out_root / f"{scenario.name}-{stamp}-{n}"
        self.run_dir.mkdir(parents=True)
        self.runtime = make_runtime(scenario, self.run_dir, log_level=log_level)
        self.run_info: dict[str, Any] = {"scenario": scenario.name, "started": time.time(), "interrupted": False}
        self.metrics = LiveMetrics(scenario)
        self.phase = "starting"
        self.observer: SwarmObserver | None = None
        self.probe = probe  # called every tick of the mission with the elapsed time (benchmarks)

    # ---- orchestration -------------------------------------------------------------------------
    def run(self) -> dict[str, Any]:
        (self.run_dir / "scenario.yaml").write_text(yaml.safe_dump(self.scn.model_dump(mode="json"), sort_keys=False))
        old = signal.signal(signal.SIGTERM, _raise_interrupt)
        try:
            self._fly()
        except KeyboardInterrupt:
            self.run_info["interrupted"] = True
            self.console.print("[yellow]interrupted: stopping every UAV process[/]")
        except RunAborted as exc:
            self.run_info["aborted"] = str(exc)
            self.console.print(f"[red]run aborted:[/] {exc}")
        finally:
            if self.observer is not None:
                self.observer.close()
            self.run_info["exit_codes"] = self.runtime.stop()
            self.run_info["stopped"] = time.time()
            (self.run_dir / "run.json").write_text(json.dumps(self.run_info, indent=2))
            signal.signal(signal.SIGTERM, old)
        return summarise_run(self.run_dir, self.scn).to_dict()

    def _fly(self) -> None:
        scn = self.scn
        net = self.runtime.start_network(scn.network.mode, scn.network.pose_feed, scn.swarm,
                                         connectivity=scn.network.connectivity, discovery=scn.network.discovery.model_dump())
        # how other tools reach this run's swarm (its edge router): `mrswarm gcs watch --run <dir>`,
        # `mrswarm netem set --run <dir>`
        network_info: dict[str, Any] = {"swarm": scn.swarm, "endpoints": list(net.endpoints)}
        if net.connectivity == "discovery" and net.options.get("server") and net.options.get("key"):
            # `mrswarm gcs nodes` completes its list from the registry (version, locators)
            key_file = self.run_dir / "discovery.keys"
            key_file.write_text(f"{scn.swarm} {net.options['key']}\n")
            key_file.chmod(0o600)
            network_info["discovery"] = {"server": net.options["server"], "key_file": key_file.name}
        (self.run_dir / "network.json").write_text(json.dumps(network_info))
        configs = scn.virtual_uav_configs(net, record_dir=str(self.run_dir))
        ids = [c.agent.uav for c in configs]
        for c in configs:
            self.runtime.start_uav(c)
        self.run_info["pids"] = self.runtime.pids()
        kind = "containers" if self.runtime.name == "docker" else "processes"
        self.console.print(f"[bold]{scn.name}[/]: {len(ids)} virtual UAV {kind}, results in {self.run_dir}")
        self.console.print(f"ground station: mrswarm gcs watch --run {self.run_dir}", highlight=False)
        # the runner joins as a client of the edge router if there is one (rendezvous, or
        # discovery with the router beside it), else as a discovery peer (role "observer")
        obs_net = NetworkConfig(connectivity="rendezvous", endpoints=net.endpoints, mode="client") if net.endpoints else net
        self.observer = SwarmObserver(scn.swarm, make_connectivity(obs_net), name="runner").open()
        n = len(ids)
        slowest = min(c.target_rtf for c in configs)
        with self._display() as refresh:
            self.phase = "waiting for UAVs"
            self._wait_phase(ids, {"ready"}, READY_TIMEOUT_BASE + READY_TIMEOUT_PER_UAV * n, refresh)
            self.phase = "taking off"
            self._command("takeoff", ids)
            climb = scn.flight.altitude / 1.5 / slowest
            self._wait_phase(ids, {"hover"}, TAKEOFF_MARGIN + climb, refresh)
            self.phase = "mission"
            self._command("start", ids)
            start = time.time()
            self.run_info["mission_start"] = start
            end = start + scn.duration
            while time.time() < end:
                self._tick(refresh, start)
                if self.probe is not None:
                    self.probe(self, time.time() - start)
                if all(self._phase_of(u) in ("done", "landed") for u in ids):
                    self.run_info["all_done_at"] = time.time() - start
                    break
            self.phase = "stopping"
            refresh()

    def _phase_of(self, uav: int) -> str:
        assert self.observer is not None
        v = self.observer.uavs.get(uav)
        return v.state.phase if v is not None and v.state is not None else "?"

    def _command(self, verb: str, ids: list[int], timeout: float = 6.0) -> None:
        """Send ``verb`` to ``ids`` and collect every ack; re-send once to the silent ones."""
        assert self.observer is not None
        acks: dict[int, Any] = {}
        pending = self.observer.command(verb, ids)
        for attempt in (1, 2):
            deadline = time.time() + timeout / 2
            while time.time() < deadline and not pending.complete:
                time.sleep(0.05)
                self.observer.poll()
            acks.update(pending.acks)
            missing = sorted(set(ids) - set(acks))
            if not missing or attempt == 2:
                break
            pending = self.observer.command(verb, missing)  # commands are idempotent
        failed = {u: a.message for u, a in acks.items() if not a.ok}
        if failed:
            raise RunAborted(f"'{verb}' refused by {failed}")
        missing = sorted(set(ids) - set(acks))
        if missing:
            raise RunAborted(f"no acknowledgement of '{verb}' from UAVs {missing}")

    def _wait_phase(self, ids: list[int], phases: set[str], timeout: float, refresh: Any) -> None:
        deadline = time.time() + timeout
        while time.time() < deadline:
            self._tick(refresh, None)
            if all(self._phase_of(u) in phases for u in ids):
                return
        behind = {u: self._phase_of(u) for u in ids if self._phase_of(u) not in phases}
        raise RunAborted(f"timed out after {timeout:.0f} s waiting for {'/'.join(sorted(phases))}; still: {behind}")

    def _tick(self, refresh: Any, start: float | None) -> None:
        assert self.observer is not None
        fresh = self.observer.poll()
        self.metrics.add_poses(self.observer, fresh)
        self.metrics.update_separation(self.observer)
        dead = {n: rc for n, rc in self.runtime.exited().items()}
        if dead:
            raise RunAborted(f"processes exited early: {dead} (see {self.run_dir / 'logs'})")
        self.elapsed = time.time() - start if start else None
        refresh()
        time.sleep(0.1)

    # ---- display ----------------------------------------------------------------------------
    def _status_table(self) -> Group:
        scn, obs, m = self.scn, self.observer, self.metrics
        phases: dict[str, int] = {}
        rtfs = []
        ages = []
        if obs is not None:
            now = time.time()
            for v in obs.uavs.values():
                if v.state is not None:
                    phases[v.state.phase] = phases.get(v.state.phase, 0) + 1
                if v.telemetry is not None and v.telemetry.rtf > 0:
                    rtfs.append(v.telemetry.rtf)
                if v.pose is not None:
                    ages.append(max(0.0, v.pose_recv - v.pose.t_wall))
        elapsed = getattr(self, "elapsed", None)
        t = Table.grid(padding=(0, 2))
        t.add_row("scenario", f"[bold]{scn.name}[/] ({len(scn.uav_list())} UAVs, swarm '{scn.swarm}')")
        t.add_row("stage", self.phase + (f"  {elapsed:5.1f} / {scn.duration:.0f} s" if elapsed is not None else ""))
        t.add_row("agents", ", ".join(f"{k} {v}" for k, v in sorted(phases.items())) or "-")
        if m.coverage is not None:
            t.add_row("coverage", f"{100 * m.coverage:5.1f} %")
        t.add_row("min separation", "-" if m.min_sep == math.inf else f"{m.min_sep_now:5.1f} m now, {m.min_sep:5.1f} m lowest")
        t.add_row("RTF", f"mean {np.mean(rtfs):.3f}, min {min(rtfs):.3f}" if rtfs else "-")
        t.add_row("pose age", f"p50 {1000 * float(np.median(ages)):.1f} ms (at the runner)" if ages else "-")
        bar = ProgressBar(total=scn.duration, completed=min(elapsed or 0.0, scn.duration), width=60)
        return Group(Panel(t, title="mrswarm run", expand=False), bar)

    def _display(self) -> Display:
        return Display(self)


class Display:
    """Live status while a run flies: a rich panel on a terminal, a line every 5 s otherwise.

    Used as ``with Display(exp) as refresh: ... refresh()``.
    """

    def __init__(self, exp: Experiment):
        self.exp = exp
        self.live: Live | None = None
        self.last_line = 0.0

    def __enter__(self) -> Callable[[], None]:
        if self.exp.live:
            self.live = Live(self.exp._status_table(), console=self.exp.console, refresh_per_second=4, transient=False)
            self.live.__enter__()
        return self.refresh

    def __exit__(self, *exc: object) -> None:
        if self.live is not None:
            self.live.__exit__(*exc)

    def refresh(self) -> None:
        exp = self.exp
        if self.live is not None:
            self.live.update(exp._status_table())
            return
        if time.time() - self.last_line < 5.0:
            return
        self.last_line = time.time()
        cov = exp.metrics.coverage
        el = getattr(exp, "elapsed", None)
        exp.console.print(
            f"[{exp.phase}]"
            + (f" t={el:.0f}s" if el is not None else "")
            + (f" coverage={100 * cov:.1f}%" if cov is not None else "")
            + ("" if exp.metrics.min_sep == math.inf else f" min_sep={exp.metrics.min_sep:.1f}m"),
            markup=False, highlight=False,
        )


def _raise_interrupt(signum: int, frame: FrameType | None) -> None:
    raise KeyboardInterrupt


def print_summary(console: Console, s: dict[str, Any]) -> None:
    t = Table(title=f"summary: {s.get('scenario')}", show_header=False)
    t.add_column(style="bold")
    t.add_column()
    sep = s.get("separation", {})
    cov = s.get("coverage")
    if cov:
        t.add_row("coverage", f"{100 * cov['final']:.1f} % (50 % at {_fmt(cov['time_to_50_s'])} s, 90 % at {_fmt(cov['time_to_90_s'])} s)")
    if "encounter" in s and s["encounter"]:
        e = s["encounter"]
        t.add_row("encounter", f"closest {e['separation_m']:.2f} m at {e['meeting_point']}, from starts {e['distance_from_start_m']}")
    if "goals" in s:
        t.add_row("goals reached", ", ".join(f"UAV {u}: {'yes' if g['reached'] else 'no'}" for u, g in s["goals"].items()))
    if sep:
        t.add_row("min separation", f"{_fmt(sep.get('min_m'))} m (safety {sep.get('safety_distance_m')} m)")
        t.add_row("collisions", str(sep.get("collisions")))
    rtf = s.get("rtf", {})
    if rtf.get("mean") is not None:
        t.add_row("RTF", f"mean {rtf['mean']:.3f}, min {rtf['min']:.3f}")
    net = s.get("network", {})
    if net:
        age = net["pose_age_ms"]
        t.add_row("pose age", f"p50 {_fmt(age['p50'])} ms, p99 {_fmt(age['p99'])} ms over {age['n']} poses")
        t.add_row("messages", f"sent {sum(net['messages_sent'].values())}, received {sum(net['messages_received'].values())}, "
                              f"rejected {sum(net['messages_rejected'].values())}, pose loss {100 * net['pose_loss']:.2f} %")
        for cls, c in (net.get("netem") or {}).get("classes", {}).items():  # docs/netem.md
            t.add_row(f"netem {cls}", f"{c['links']} links: delay mean {_fmt(c['delay_ms']['mean'])} ms, p99 "
                                      f"{_fmt(c['delay_ms']['p99'])} ms, lost {100 * c['loss']:.2f} %, reordered {c['reordered']}")
    t.add_row("results", f"{s.get('run_dir')}/summary.json" + (f", {s['plot']}" if s.get("plot") else ""))
    if s.get("aborted"):
        t.add_row("aborted", str(s["aborted"]))
    console.print(t)


def _fmt(v: Any) -> str:
    return "-" if v is None else (f"{v:.1f}" if isinstance(v, float) else str(v))
