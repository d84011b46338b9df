"""``mrswarm run``: launch a scenario, fly it, stop every process, summarise.

Sequence: the runtime (deploy/) starts the network and one process (or container) per virtual
UAV. By default (``network.connectivity: discovery``) the network is a discovery server that
introduces the UAVs to each other, which then exchange poses peer to peer, plus an edge router
beside it: the way in for the runner and for ground stations (``mrswarm gcs watch --run``);
``connectivity: rendezvous`` starts one rendezvous router instead. Then: wait until every agent
reports ``ready`` -> command ``takeoff`` -> wait until all ``hover`` -> command ``start`` (the
mission clock starts here, for every UAV at once) -> fly for ``duration`` seconds or until all
are ``done`` -> stop every process -> summarise the run folder (mrswarm/results.py).
Ctrl-C (or SIGTERM) at any point still stops every process and summarises what was recorded.

Concerns elsewhere: the live estimates and the mission clock in mrswarm/live.py, the live panel
in mrswarm/display.py, the printed summary in mrswarm/summary_table.py.
"""

from __future__ import annotations

import json
import signal
import time
from collections.abc import Callable
from pathlib import Path
from types import FrameType
from typing import Any

import yaml
from rich.console import Console

from mrswarm.display import Display
from mrswarm.live import LiveMetrics, RunProgress, RunStage
from mrswarm.recorder.run_recorder import RunRecorder
from mrswarm.results import summarise_run
from mrswarm.runtime import make_runtime
from mrswarm.scenario import Scenario
from mrswarm.summary import RunInfo, RunSummary
from mrswarm.world_setup import (
    open_observer,
    other_swarm_credentials,
    other_swarm_keys,
    swarm_networks,
    uav_configs,
    world_service_config,
    write_world_config,
)
from swarmnet.observer import SwarmObserver
from swarmnet.schema import to_builtins
from uav_stack.phases import FINISHED, AgentPhase

READY_TIMEOUT_BASE = 30.0  # s for every agent to report "ready" ...
READY_TIMEOUT_PER_UAV = 0.6  # ... plus this per UAV (processes start one after another)
TAKEOFF_MARGIN = 30.0  # s to reach "hover", on top of the climb time at the slowest UAV's RTF
CLIMB_RATE = 1.5  # m/s, the agent's takeoff climb (conservative)
COMMAND_TIMEOUT = 6.0  # s to collect every acknowledgement of a command (re-sent once halfway)
TICK = 0.1  # s between two polls of the swarm while waiting or flying


class RunAborted(RuntimeError):
    """The runner gives up: a UAV refused or ignored a command, missed a phase in time, or its process died."""


class Experiment:
    """One run of a scenario: a fresh results folder, the runtime's processes, the orchestration.

    ``probe`` (benchmarks) is called on every tick of the mission with the experiment and the
    seconds since the mission started.
    """

    def __init__(self, scenario: Scenario, out_root: Path = Path("results"), console: Console | None = None,
                 live: bool = True, log_level: str = "INFO", probe: Callable[[Experiment, float], None] | None = None,
                 record: bool = True):
        self.scn = scenario
        self.console = console or Console()
        stamp = time.strftime("%Y%m%d-%H%M%S")
        self.run_dir = out_root / f"{scenario.name}-{stamp}"
        n = 1
        while self.run_dir.exists():
            n += 1
            self.run_dir = out_root / f"{scenario.name}-{stamp}-{n}"
        self.run_dir.mkdir(parents=True)
        self.run_info = RunInfo(scenario=scenario.name, started=time.time())
        self.keys = self._credentials()
        self.swarm_keys = {scenario.swarm: self.keys, **other_swarm_credentials(scenario, self.run_dir, self.keys is not None)}
        self.runtime = make_runtime(scenario, self.run_dir, log_level=log_level)
        self.progress = RunProgress(duration=scenario.duration)
        self.metrics = LiveMetrics(scenario)
        self.display = Display(self.console, live, scenario, self.progress, self.metrics)
        self.observer: SwarmObserver | None = None
        self.probe = probe
        self.record = record  # the flight recorder: every message into <run>/run.mcap (docs/recording.md)
        self.recorder: RunRecorder | None = None

    def _credentials(self) -> Path | None:
        """The swarm's key directory for this run (docs/security.md), or None with ``network.security: off``."""
        from mrswarm.run_keys import RUN_KEYS, check_keys, run_identities, throwaway_keys
        from swarmnet.security.pki import KeysError

        sec = self.scn.network.secured
        self.run_info.security = str(sec.mode)
        if not sec.enabled:
            self.console.print("[yellow]warning: network.security: off: plain TCP without access control; anyone who "
                               "reaches this machine's network can command or impersonate the UAVs[/]")
            return None
        names = run_identities(self.scn.swarm, [u.id for u in self.scn.uav_list()])
        try:
            if sec.keys is not None:
                return check_keys(Path(sec.keys), self.scn.swarm, names)
            return throwaway_keys(self.run_dir / RUN_KEYS, self.scn.swarm, names)
        except KeysError as exc:
            raise RuntimeError(f"network.security.keys: {exc}") from None

    def run(self) -> RunSummary:
        """Fly the scenario, stop every process, write run.json, then summary.json and the figures."""
        (self.run_dir / "scenario.yaml").write_text(yaml.safe_dump(to_builtins(self.scn), sort_keys=False))
        old = signal.signal(signal.SIGTERM, _raise_interrupt)
        try:
            self._fly()
        except KeyboardInterrupt:
            self.run_info.interrupted = True
            self.console.print("[yellow]interrupted: stopping every UAV process[/]")
        except RunAborted as exc:
            self.run_info.aborted = str(exc)
            self.console.print(f"[red]run aborted:[/] {exc}")
        finally:
            if self.observer is not None:
                self.observer.close()
            self.run_info.exit_codes = dict(self.runtime.stop())
            self.run_info.stopped = time.time()
            self.run_info.write(self.run_dir / "run.json")
            if self.recorder is not None and self.recorder.stop() not in (0, 130):  # after run.json, which it keeps
                self.console.print(f"[yellow]the flight recorder failed[/] (see {self.run_dir / 'logs' / 'recorder.log'})")
            signal.signal(signal.SIGTERM, old)
        return summarise_run(self.run_dir, self.scn)

    def _fly(self) -> None:
        scn = self.scn
        discovery_keys = other_swarm_keys(scn)  # swarms sharing the airspace, each with its own key (docs/world.md)
        net = self.runtime.start_network(scn.network.mode, scn.network.pose_feed, scn.swarm,
                                         connectivity=scn.network.connectivity or "discovery", discovery=scn.network.discovery,
                                         keys=self.keys, extra_keys=discovery_keys)
        # how other tools reach this run's swarm (its edge router): `mrswarm gcs watch --run <dir>`,
        # `mrswarm netem set --run <dir>`; with the key directory they speak as gcs-1 and ctl
        network_info: dict[str, Any] = {"swarm": scn.swarm, "endpoints": list(net.endpoints),
                                        "security": {"mode": "mtls", "keys": str(self.keys)} if self.keys else {"mode": "off"}}
        if net.discovery is not None and net.discovery.key:
            # `mrswarm gcs nodes` completes its list from the registry (version, locators)
            key_file = self.run_dir / "discovery.keys"
            key_file.write_text(f"{scn.swarm} {net.discovery.key}\n")
            key_file.chmod(0o600)
            network_info["discovery"] = {"server": net.discovery.server, "key_file": key_file.name}
        (self.run_dir / "network.json").write_text(json.dumps(network_info))
        if self.record:  # before the first UAV, so its first pose is recorded
            try:
                self.recorder = RunRecorder.start(self.run_dir)
                self.console.print(f"flight recording: {self.recorder.path}", highlight=False)
            except RuntimeError as exc:  # a run without its recording still flies
                self.console.print(f"[yellow]no flight recording:[/] {exc}", highlight=False)
        nets = swarm_networks(scn, net, self.runtime, discovery_keys, self.swarm_keys)
        world = world_service_config(scn, nets, self.swarm_keys, self.run_dir)
        if world is not None:  # before the UAVs, so that it tracks them from their first pose
            self.runtime.start_world(write_world_config(world, self.run_dir))
        configs = uav_configs(scn, nets, record_dir=str(self.run_dir))
        ids = [c.agent.uav for c in configs]
        for c in configs:
            self.runtime.start_uav(c)
        self.run_info.pids = self.runtime.pids()
        kind = "containers" if self.runtime.name == "docker" else "processes"
        self.console.print(f"[bold]{scn.name}[/]: {len(ids)} virtual UAV {kind}, results in {self.run_dir}")
        self.console.print(f"ground station: mrswarm gcs watch --run {self.run_dir}", highlight=False)
        # the runner joins as a client of the edge router if there is one (rendezvous, or
        # discovery with the router beside it), else as a discovery peer (role "observer"), as ctl
        # (with the run's key directory as seen from here: a container's credentials sit elsewhere);
        # one observer per swarm when several share the airspace
        self.observer = open_observer(scn, nets, self.swarm_keys)
        n = len(ids)
        slowest = min(c.target_rtf for c in configs)
        with self.display:
            self.progress.stage = RunStage.WAITING
            self._wait_phase(ids, {AgentPhase.READY}, READY_TIMEOUT_BASE + READY_TIMEOUT_PER_UAV * n)
            self.progress.stage = RunStage.TAKING_OFF
            self._command("takeoff", ids)
            climb = scn.flight.altitude / CLIMB_RATE / slowest
            self._wait_phase(ids, {AgentPhase.HOVER}, TAKEOFF_MARGIN + climb)
            self.progress.stage = RunStage.MISSION
            self._command("start", ids)
            start = time.time()
            self.run_info.mission_start = self.progress.mission_start = start
            end = start + scn.duration
            while time.time() < end:
                self._tick()
                if self.probe is not None:
                    self.probe(self, time.time() - start)
                if all(self._phase_of(u) in FINISHED for u in ids):
                    self.run_info.all_done_at = time.time() - start
                    break
            self.progress.stage = RunStage.STOPPING
            self.display.refresh(self.observer)

    def _phase_of(self, uav: int) -> AgentPhase | None:
        """The phase ``uav`` last reported (None: nothing yet, or a name this version does not know)."""
        assert self.observer is not None
        v = self.observer.uavs.get(uav)
        if v is None or v.state is None:
            return None
        try:
            return AgentPhase(v.state.phase)
        except ValueError:
            return None

    def _command(self, verb: str, ids: list[int], timeout: float = COMMAND_TIMEOUT) -> None:
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

    def _wait_phase(self, ids: list[int], phases: set[AgentPhase], timeout: float) -> None:
        """Poll until every UAV in ``ids`` reports one of ``phases``; RunAborted after ``timeout`` s."""
        deadline = time.time() + timeout
        while time.time() < deadline:
            self._tick()
            if all(self._phase_of(u) in phases for u in ids):
                return
        behind = {u: str(self._phase_of(u) or "?") for u in ids if self._phase_of(u) not in phases}
        raise RunAborted(f"timed out after {timeout:.0f} s waiting for {'/'.join(sorted(phases))}; still: {behind}")

    def _tick(self) -> None:
        """One poll of the swarm: live metrics, a dead process check, the display, then TICK s of sleep."""
        assert self.observer is not None
        fresh = self.observer.poll()
        self.metrics.add_poses(self.observer, fresh)
        self.metrics.update_separation(self.observer)
        dead = self.runtime.exited()
        if dead:
            raise RunAborted(f"processes exited early: {dead} (see {self.run_dir / 'logs'})")
        self.display.refresh(self.observer)
        time.sleep(TICK)


def _raise_interrupt(signum: int, frame: FrameType | None) -> None:
    raise KeyboardInterrupt
