"""``mrswarm run``: launch a scenario, fly it, stop every process, summarise.

Sequence: the runtime (deploy/) starts the network and one process (or container) per virtual
UAV. By default, up to 25 UAVs (``network.connectivity: discovery``), the network is a discovery
server that introduces the UAVs to each other, which then exchange poses peer to peer, plus an
edge router beside it: the way in for the runner and for ground stations (``mrswarm gcs watch
--run``); ``connectivity: rendezvous`` (the default above 25 UAVs, with every UAV its client)
starts one rendezvous router instead. Then: wait until every agent
reports ``ready`` -> command ``takeoff`` -> wait until all ``hover`` -> command ``start`` (the
mission clock starts here, for every UAV at once) -> fly for ``duration`` seconds or until all
are ``done`` -> stop every process -> summarise the run folder (mrswarm/results/summarise.py).
Ctrl-C, SIGTERM or SIGHUP at any point still stops every process and summarises what was
recorded; a second one stops faster (mrswarm/run/signals.py).

A UAV whose flight controller is external (``uavs[].fcu``: a real autopilot, a SITL) gets only
its agent, started first (``Runtime.start_agent``), or, with ``agent: companion``, the
configuration its companion computer's agent reads, and the run waits for it; each has its own
wait (``wait_s``). Before the processes stop, every external UAV off the ground is landed.

A process that exits is an event, not the end of the run (mrswarm/run/supervisor.py): the edge
services are restarted, a lost UAV is recorded and the swarm flies on (``fleet.restart:
on-failure`` starts it again and it rejoins). The scenario's ``faults:`` are injected during the
mission (mrswarm/run/chaos.py). The runner's own files are written atomically; one that cannot be
written (a full disk) is reported, never the end of the run.

Concerns elsewhere: the live estimates and the mission clock in mrswarm/run/live.py, the live panel
in mrswarm/run/display.py, the printed summary in mrswarm/results/summary_table.py.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml
import zenoh
from rich.console import Console
from rich.markup import escape

from groundfloor.errors import MrswarmError
from groundfloor.files import write_atomic
from groundfloor.schema import to_builtins
from mrswarm.recorder.run_recorder import STOP_TIMEOUT, RunRecorder
from mrswarm.records.summary import RECORDER, LateUav, ProcessEvent, RunInfo, RunSummary, uav_of
from mrswarm.results.summarise import summarise_run
from mrswarm.results.wording import format_ids, plural
from mrswarm.run.chaos import Chaos, Swarm
from mrswarm.run.command_round import CommandRound, command_deadline, command_round
from mrswarm.run.display import Display
from mrswarm.run.live import LiveMetrics, RunProgress, RunStage
from mrswarm.run.runtime import make_runtime
from mrswarm.run.signals import FAST_GRACE_S, GRACE_S, GRACE_S_PER_PROCESS, Interrupted, StopSignals
from mrswarm.run.stalls import StallWatch
from mrswarm.run.supervisor import RunnerChildren, Supervisor
from mrswarm.run.world_setup import (
    external_agents,
    open_observer,
    other_swarm_credentials,
    uav_configs,
    world_service_config,
    write_world_config,
)
from mrswarm.scenario import MESH_MAX_UAVS, Scenario
from mrswarm.scenario.faults import plan
from swarmnet.keyspace import SwarmKeys
from swarmnet.lockstep import LOCKSTEP_EPOCH, LockstepLeader, LockstepStalled
from swarmnet.observer import SwarmObserver
from uav_stack.config import AgentConfig, NetworkConfig, VirtualUavConfig
from uav_stack.phases import FINISHED, WORKING, AgentPhase
from uav_stack.runtime import tick_hz_for

READY_TIMEOUT_BASE = 30.0  # s for every agent to report "ready" ...
READY_TIMEOUT_PER_UAV = 0.6  # ... plus this per UAV (processes start one after another)
# past that, the wait goes on while UAVs keep getting ready (no new one for READY_STALL_S: give up),
# up to READY_TIMEOUT_CAP_PER_UAV s per UAV: 100 UAVs starting at once on 2 cores need about 2 min
READY_STALL_S = 30.0
READY_TIMEOUT_CAP_PER_UAV = 3.0
TAKEOFF_MARGIN = 30.0  # s to reach "hover", on top of the climb time at the slowest UAV's RTF
CLIMB_RATE = 1.5  # m/s, the agent's takeoff climb (conservative)
TICK = 0.1  # s between two polls of the swarm while waiting or flying
# lock-step time: s of simulated time between two polls of the mission loop (the runner's look between ticks
# holds every pool; waiting for a phase and commands look every TICK, as in real time)
LOCKSTEP_LOOK_S = 0.5
REJOIN_EVERY_S = 2.0  # a restarted UAV is sent start (or takeoff) this often until it flies
# at most this fraction of the virtual UAVs may be late at a stage (not ready, not airborne, not acknowledging in
# time): the run goes on without them, records them as late, and sends them the command until they fly with the
# others; more than that, and the run gives up (RunAborted). Small fleets: none may be late
LATE_MAX_FRACTION = 0.1
LAND_SPEED = 0.5  # m/s: the slowest final descent of an autopilot's landing (ArduCopter's LAND_SPEED), for its wait
LAND_MARGIN_S = 30.0  # s on top of that to land the external UAVs at the end of a run
LAND_RESEND_S = 2.0  # an external UAV that does not show its landing is sent 'land' again this often
ON_GROUND = frozenset({AgentPhase.INIT, AgentPhase.READY, AgentPhase.LANDED, AgentPhase.KILLED})


class RunAborted(RuntimeError, MrswarmError):
    """The runner gives up: a UAV refused or ignored a command, missed a phase in time, or its process died."""


class Experiment:
    """One run of a scenario: a fresh results folder, the runtime's processes, the orchestration.

    ``probe`` (benchmarks) is called on every tick of the mission with the experiment and the
    seconds since the mission started.
    """

    def __init__(self, scenario: Scenario, out_root: Path = Path("results"), console: Console | None = None,
                 live: bool = True, log_level: str = "INFO", probe: Callable[[Experiment, float], None] | None = None,
                 record: bool = True, signals: StopSignals | None = None):
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
        self.mavlink_key_file: Path | None = None  # the passphrase the routers use (network.json names it)
        self.mavlink_key = self._mavlink_key()
        self.swarm_keys = {scenario.swarm: self.keys, **other_swarm_credentials(scenario, self.run_dir, self.keys is not None)}
        self.runtime = make_runtime(scenario, self.run_dir, log_level=log_level)
        self.progress = RunProgress(duration=scenario.duration)
        self.metrics = LiveMetrics(scenario)
        self.display = Display(self.console, live, scenario, self.progress, self.metrics)
        self.observer: SwarmObserver | None = None
        self.probe = probe
        self.record = record  # the flight recorder: every message into <run>/run.mcap (docs/recording.md)
        self.recorder: RunRecorder | None = None
        self.signals = signals or StopSignals()
        self.supervisor: Supervisor | None = None
        self.chaos: Chaos | None = None
        self.ids: list[int] = []
        self.lost: set[int] = set()  # UAVs whose process exited and is not (yet) back
        self.rejoin: dict[int, tuple[float, float]] = {}  # restarted UAV -> (restart time, next start command), until it flies
        self.stalls = StallWatch()  # UAVs alive but silent (SIGSTOP, starved): events with their duration
        self._linked_since: float | None = None  # the runner's link to the edge router up since (wall)
        # the run's clock: the wall's, or with time: lockstep the leader's simulated time (swarmnet/lockstep.py)
        self.now: Callable[[], float] = time.time
        self.progress.clock = lambda: self.now()
        self.leader: LockstepLeader | None = None

    def _credentials(self) -> Path | None:
        """The swarm's key directory for this run (docs/security.md), or None with ``network.security: off``."""
        from mrswarm.run.keys import RUN_KEYS, check_keys, run_identities, throwaway_keys
        from swarmnet.security.pki import KeysError

        sec = self.scn.network.secured
        self.run_info.security = str(sec.mode)
        if not sec.enabled:
            self.console.print("[yellow]warning: network.security: off: plain TCP without access control; anyone who "
                               "reaches this machine's network can command or impersonate the UAVs[/]")
            return None
        names = run_identities(self.scn.swarm, [u.id for u in self.scn.uav_list()])
        pools = self.scn.pool_numbers(self.scn.swarm)  # each pool's one session (docs/scale.md)
        try:
            if sec.keys is not None:
                return check_keys(Path(sec.keys), self.scn.swarm, names, pools)
            return throwaway_keys(self.run_dir / RUN_KEYS, self.scn.swarm, names, pools=pools)
        except KeysError as exc:
            raise RuntimeError(f"network.security.keys: {exc}") from None

    def _mavlink_key(self) -> Path | None:
        """The MAVLink signing passphrase of the UAVs' routers when it is not in their key directories
        (docs/security.md): the scenario's ``gcs.signing.key_file``, else, with ``network.security:
        off``, a throw-away one in ``<run>/mavlink.key``. With the run's key directory, its
        ``mavlink.key`` (None here). Says in ``run.json`` what the routers accept."""
        from swarmnet.security.roster import MAVLINK_KEY_FILE
        from uav_stack.mavlink_signing import SigningKeyError, read_key_file, write_key_file

        g = self.scn.gcs
        if not g.mavlink:
            self.run_info.mavlink = "off"
            return None
        path: Path | None = None
        if g.signing is not None and g.signing.key_file is not None:
            path = Path(g.signing.key_file)
            try:
                read_key_file(path)
            except SigningKeyError as exc:
                raise RuntimeError(f"gcs.signing.key_file: {exc}") from None
        elif self.keys is None:
            path = write_key_file(self.run_dir / MAVLINK_KEY_FILE)
        key = path if path is not None else (self.keys / MAVLINK_KEY_FILE if self.keys is not None else None)
        if key is None or not key.is_file():
            self.console.print(f"[yellow]warning: no MAVLink signing key ({key}): the UAVs' MAVLink routers send "
                               "telemetry and accept no command; `mrswarm keys mavlink --dir DIR --new` makes one[/]")
            key = None
        self.run_info.mavlink = "unsigned-allowed" if g.allow_unsigned else "signed" if key is not None else "telemetry-only"
        if g.allow_unsigned:
            self.console.print("[yellow]warning: gcs.allow_unsigned: the UAVs' MAVLink routers accept unsigned commands: "
                               "any process that reaches their endpoints (on this machine: any) can command every UAV[/]")
        self.mavlink_key_file = key
        return path

    def run(self) -> RunSummary:
        """Fly the scenario, stop every process, write run.json, then summary.json and the figures."""
        own_signals = not self.signals.installed
        if own_signals:
            self.signals.install()
        try:
            self._save("scenario.yaml", yaml.safe_dump(to_builtins(self.scn), sort_keys=False).encode())
            self._save_info()
            try:
                self._fly()
            except Interrupted:
                self.run_info.interrupted = True
                self._say(f"[yellow]{self.signals.names[0]}: stopping every UAV process[/]")
            except RunAborted as exc:
                self.run_info.aborted = str(exc)
                self._say(f"[red]run aborted:[/] {exc}")
            except OSError as exc:  # the results folder cannot take a UAV's configuration (a full or read-only disk)
                self.run_info.aborted = f"cannot start: {exc.filename or ''}: {exc.strerror or exc}"
                self._say(f"[red]run aborted:[/] {self.run_info.aborted}")
            finally:
                self._stop_all()
            if self.signals.hangup:
                self.console.quiet = True  # the terminal is gone
            # the runner's own record: run.json may be missing its last writes (a full disk)
            return summarise_run(self.run_dir, self.scn, stop=lambda: self.signals.fast, info=self.run_info)
        finally:
            if own_signals:
                self.signals.restore()

    def _stop_all(self) -> None:
        """Land the external UAVs, stop every child (faster after a second signal) and write run.json; never
        raises on a dead observer."""
        if self.observer is not None and self.supervisor is not None:
            self._watch_stalls(final=True)  # a UAV still stalled now: its stall lasted to the end
        if self.leader is not None:  # how fast simulated time ran
            self.run_info.lockstep = self.leader.stats()
            try:
                self.leader.close()
            except Exception as exc:  # noqa: BLE001 - stopping must go on
                self.run_info.write_errors.append(f"lock-step leader close: {exc}")
        try:
            self._land_external()
        except Exception as exc:  # noqa: BLE001 - stopping must go on
            self._say(f"[yellow]landing the external UAVs failed:[/] {escape(str(exc))}")
        if self.observer is not None:
            try:
                self.observer.close()
            except Exception as exc:  # noqa: BLE001 - stopping must go on
                self.run_info.write_errors.append(f"observer close: {exc}")
        grace = FAST_GRACE_S if self.signals.fast else GRACE_S + GRACE_S_PER_PROCESS * len(self.scn.all_uavs())
        self.run_info.stopping = self.now()  # (lock-step: the simulated time the clock stopped at, as the records)
        self.run_info.exit_codes = dict(self.runtime.stop(grace))
        self.run_info.stopped = self.now()
        self.run_info.stop_signals = self.signals.names
        self.run_info.interrupted = self.run_info.interrupted or self.signals.requested
        self._save_info()
        # the flight recorder after run.json, which it keeps; faster after a second signal
        if self.recorder is not None:
            code = self.recorder.stop(FAST_GRACE_S if self.signals.fast else STOP_TIMEOUT)
            self.run_info.exit_codes[RECORDER] = code
            if code not in (0, 130):
                self._say(f"[yellow]the flight recorder failed[/] (see {self.run_dir / 'logs' / 'recorder.log'})")
            self.run_info.recording_files = list(self.recorder.files)
            self.run_info.recording_unwritten = self.recorder.unwritten
            self._save_info()

    # ---- the run's files: atomic, and a failure is reported, not fatal ---------------------------------------
    def _save(self, name: str, data: bytes) -> bool:
        try:
            write_atomic(self.run_dir / name, data, fsync=True)
            return True
        except OSError as exc:
            msg = f"{name}: {exc.strerror or exc}"
            if msg not in self.run_info.write_errors:
                self.run_info.write_errors.append(msg)
                self._say(f"[yellow]warning:[/] cannot write {self.run_dir / name} ({exc.strerror or exc}); the run goes on")
            return False

    def _save_info(self) -> None:
        if self.supervisor is not None:
            self.run_info.events = list(self.supervisor.events)
        if self.chaos is not None:
            self.run_info.faults = list(self.chaos.records)
            self.chaos.changed = False
        try:
            self.run_info.write(self.run_dir / "run.json")
        except OSError as exc:
            msg = f"run.json: {exc.strerror or exc}"
            if msg not in self.run_info.write_errors:
                self.run_info.write_errors.append(msg)
                self._say(f"[yellow]warning:[/] cannot write {self.run_dir / 'run.json'} ({exc.strerror or exc}); "
                          "the run goes on")

    def _say(self, text: str) -> None:
        """Print, unless the terminal is gone (after SIGHUP a write to it fails)."""
        try:
            self.console.print(text, highlight=False, soft_wrap=not self.console.is_terminal)  # a pipe: unfolded lines
        except OSError:
            self.console.quiet = True

    def _fly(self) -> None:
        scn = self.scn
        connectivity, mode, pose_feed = scn.network.topology
        n = len(scn.all_uavs())
        if n > MESH_MAX_UAVS:  # the network may not be the one a small run gets: say which it is
            self._say(f"network: {n} UAVs on this machine: {connectivity}, {mode} mode, {pose_feed} pose feed (what "
                      f"the scenario does not set is chosen for more than {MESH_MAX_UAVS} UAVs: docs/scale.md)")
        # every swarm of the airspace, each with its own key directory and discovery key (docs/world.md)
        nets = self.runtime.start_network(scn.network_plan(self.swarm_keys))
        net = nets[scn.swarm]
        # how other tools reach this run's swarm (its edge router): `mrswarm gcs watch --run <dir>`,
        # `mrswarm netem set --run <dir>`; with the key directory they speak as gcs-1 and ctl
        network_info: dict[str, Any] = {"swarm": scn.swarm, "endpoints": list(net.endpoints),
                                        "security": {"mode": "mtls", "keys": str(self.keys)} if self.keys else {"mode": "off"}}
        if self.mavlink_key_file is not None:  # `mrswarm keys mavlink --run <dir>` prints it for QGroundControl and MAVProxy
            network_info["mavlink"] = {"mode": self.run_info.mavlink, "key_file": str(self.mavlink_key_file.resolve())}
        if net.discovery is not None and net.discovery.key:
            # `mrswarm gcs nodes` completes its list from the registry (version, locators)
            key_file = self.run_dir / "discovery.keys"
            write_atomic(key_file, f"{scn.swarm} {net.discovery.key}\n", private=True)
            network_info["discovery"] = {"server": net.discovery.server, "key_file": key_file.name}
        self._save("network.json", json.dumps(network_info).encode())
        if self.record:  # before the first UAV, so its first pose is recorded
            try:
                self.recorder = RunRecorder.start(self.run_dir, lockstep=scn.time == "lockstep")
                self.run_info.recording_files = list(self.recorder.files)
                self._say(f"flight recording: {self.recorder.path}")
            except (RuntimeError, OSError) as exc:  # a run without its recording still flies
                self.console.print(f"[yellow]no flight recording:[/] {exc}", highlight=False)
        world = world_service_config(scn, nets, self.swarm_keys, self.run_dir)
        if world is not None:  # before the UAVs, so that it tracks them from their first pose
            self.runtime.start_world(write_world_config(world, self.run_dir))
        configs = uav_configs(scn, nets, record_dir=str(self.run_dir), mavlink_key=self.mavlink_key)
        agents = external_agents(scn, nets, record_dir=str(self.run_dir), mavlink_key=self.mavlink_key)
        self.ids = ids = [a.uav for a in agents] + [c.agent.uav for c in configs]
        for a in agents:  # first: a real autopilot may take its time to be ready (GPS lock, EKF)
            self.signals.check()
            self._start_external(a)
        pools: dict[str, tuple[int, ...]] = {}  # pool process -> its UAVs (fleet.pool > 1)
        lockstep = scn.time == "lockstep"
        for group in scn.pools(configs):
            self.signals.check()
            if scn.pool_size == 1:
                self.runtime.start_uav(group[0])
                continue
            number = len(pools) + 1
            name = f"pool{number}"
            pools[name] = tuple(c.agent.uav for c in group)
            self.runtime.start_pool(name, group, number, lockstep_epoch=LOCKSTEP_EPOCH if lockstep else None)
        self.run_info.pools = {name: list(uavs) for name, uavs in pools.items()}
        # the runtime's processes and the runner's flight recorder, each restarted as it should be
        children = RunnerChildren(self.runtime, {RECORDER: self.recorder} if self.recorder is not None else {})
        self.run_info.pids = children.pids()
        restart = scn.fleet is not None and scn.fleet.restart == "on-failure"
        self.supervisor = Supervisor(children, clock=lambda: self.now(), restart_uavs=restart,
                                     last_pose=self._last_pose, log_of=lambda name: self.run_dir / "logs" / f"{name}.log",
                                     pools=pools)
        self.supervisor.adopt()
        self._save_info()
        one = len(configs) == 1
        kind = ("container" if one else "containers") if self.runtime.name == "docker" else ("process" if one else "processes")
        if pools:
            fleet = f"{len(configs)} virtual UAVs in {len(pools)} pool{'s' if len(pools) > 1 else ''} (fleet.pool)"
        else:
            fleet = f"{len(configs)} virtual UAV {kind}"
        if agents:
            fleet += f" and {len(agents)} UAV{'s' if len(agents) > 1 else ''} with an external flight controller"
        self._say(f"[bold]{scn.name}[/]: {fleet}, results in {self.run_dir}")
        self._say(f"ground station: mrswarm gcs watch --run {self.run_dir}")
        if scn.gcs.mavlink and scn.gcs.port is not None:
            self._say(f"MAVLink: QGroundControl or MAVProxy on udp {scn.gcs.host}:{scn.gcs.port} (system id = UAV id up to "
                      "240, docs/gcs.md); " + {
                          "signed": f"commands signed with the key: mrswarm keys mavlink --run {self.run_dir}",
                          "unsigned-allowed": "[yellow]unsigned commands accepted (gcs.allow_unsigned)[/]",
                      }.get(str(self.run_info.mavlink), "telemetry only (no signing key)"))
        # the runner joins as a client of the edge router if there is one (rendezvous, or
        # discovery with the router beside it), else as a discovery peer (role "observer"), as ctl
        # (with the run's key directory as seen from here: a container's credentials sit elsewhere);
        # one observer per swarm when several share the airspace
        try:
            self.observer = open_observer(scn, nets, self.swarm_keys, clock=lambda: self.now())
        except zenoh.ZError as exc:  # the edge router never accepted the runner: every UAV is stopped, the run says why
            raise RunAborted(f"the runner could not join the swarm: {exc}") from None
        if lockstep:
            self._start_lockstep(configs, len(pools))
        n = len(ids)
        slowest = min([c.target_rtf for c in configs] or [1.0])
        ready_own = {u.id: u.wait_s for u in scn.external_uavs()}  # each external UAV its own wait
        with self.display:
            self.progress.stage = RunStage.WAITING
            self._wait_phase(ids, {AgentPhase.READY}, READY_TIMEOUT_BASE + READY_TIMEOUT_PER_UAV * n,
                             stall=READY_STALL_S, cap=READY_TIMEOUT_BASE + READY_TIMEOUT_CAP_PER_UAV * n, own=ready_own)
            self.progress.stage = RunStage.TAKING_OFF
            takeoff = self._command("takeoff", ids, {AgentPhase.ARMING, AgentPhase.TAKEOFF, AgentPhase.OFFBOARD,
                                                     AgentPhase.HOVER})
            self.run_info.takeoff_sent, self.run_info.takeoff_sends = takeoff.sent_at, takeoff.sends
            self.run_info.takeoff_acked_s = takeoff.duration
            self.run_info.takeoff_by_state = len(takeoff.by_state)
            climb = scn.flight.altitude / CLIMB_RATE / slowest
            hover_s = TAKEOFF_MARGIN + climb + command_deadline(n)
            # a real autopilot may take longer to arm and climb (pre-arm checks, its own climb rate)
            self._wait_phase(ids, {AgentPhase.HOVER}, hover_s, own={u: hover_s + TAKEOFF_MARGIN for u in ready_own})
            self.run_info.all_airborne_s = self.now() - takeoff.sent_at
            self.progress.reached(f"all {n} airborne {self.run_info.all_airborne_s:.1f} s after takeoff")
            self.progress.stage = RunStage.MISSION
            started = self._command("start", ids, set(WORKING))
            # (lock-step: the acknowledgements are seen at the runner's next look, a tick later at the earliest;
            # the command's own time is exact, and the UAVs take it at the next tick)
            start = started.sent_at if self.leader is not None else self.now()
            self.run_info.mission_start = self.progress.mission_start = start
            if scn.faults:
                self.chaos = Chaos(plan(scn.faults, scn.seed), self._swarm(net), clock=self.now)
            self._save_info()
            end = start + scn.duration
            while self.now() < end:
                self._tick(LOCKSTEP_LOOK_S)
                if self.chaos is not None:
                    self.chaos.tick(self.now() - start)
                    if self.chaos.changed:
                        self._save_info()
                if self.probe is not None:
                    self.probe(self, self.now() - start)
                active = self._active_ids()
                if active and not self.rejoin and all(self._finished(u) for u in active) \
                        and (self.chaos is None or not self.chaos.pending):
                    self.run_info.all_done_at = self.now() - start
                    break
            self.progress.stage = RunStage.STOPPING
            self.display.refresh(self.observer)

    def _start_lockstep(self, configs: list[VirtualUavConfig], pools: int) -> None:
        """time: lockstep: the runner leads the clock (swarmnet/lockstep.py) once every pool is ready for
        it; from then on the run's clock is simulated time, stepped at each of its looks (_step_clock)."""
        assert self.observer is not None and self.observer.node.session is not None
        period = 1.0 / max(tick_hz_for(c.agent) for c in configs)
        self.leader = LockstepLeader(self.observer.node.session, SwarmKeys(self.scn.swarm), range(1, pools + 1), period,
                                     LOCKSTEP_EPOCH, world=self.scn.world is not None)
        self.progress.detail = f"waiting for {plural(pools, 'pool')} to take lock-step time" + (
            " and the world service" if self.scn.world is not None else "")
        try:
            self.leader.wait_ready(READY_TIMEOUT_BASE + READY_TIMEOUT_PER_UAV * len(configs))
        except LockstepStalled as exc:
            raise RunAborted(f"lock-step time: {exc} ({format_ids(exc.missing)}; see {self.run_dir / 'logs'})") from None
        self.now = self.leader.clock
        self._say(f"lock-step time: {plural(pools, 'pool')} on the simulated clock, as fast as they run")

    def _swarm(self, net: NetworkConfig) -> Swarm:
        """What the fault schedule acts on."""
        d = net.discovery
        return Swarm(runtime=self.runtime, supervisor=self.supervisor, observer=self.observer,
                     base_netem=to_builtins(self.scn.network.netem) if self.scn.network.netem is not None else None,
                     discovery=(d.server, self.scn.swarm, d.read_key()) if d is not None else None, ids=list(self.ids))

    def _active_ids(self) -> list[int]:
        """UAVs flying with the swarm now: not lost, not rejoining."""
        return [u for u in self.ids if u not in self.lost and u not in self.rejoin]

    def _last_pose(self, uav: int) -> list[float] | None:
        v = self.observer.uavs.get(uav) if self.observer is not None else None
        return [round(v.pose.x, 2), round(v.pose.y, 2), round(v.pose.z, 2)] if v is not None and v.pose is not None else None

    def _finished(self, uav: int) -> bool:
        """The UAV's mission is over: done, or landed by its mission (``land_when_done``). A UAV landed by
        an operator (``override`` set) counts only with ``gcs.landing_ends_run``: it may be relaunched."""
        phase = self._phase_of(uav)
        if phase not in FINISHED:
            return False
        if phase != AgentPhase.LANDED or self.scn.gcs.landing_ends_run:
            return True
        assert self.observer is not None
        v = self.observer.uavs.get(uav)
        return v is not None and v.state is not None and not v.state.override

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

    def _command(self, verb: str, ids: list[int], took_effect: set[AgentPhase]) -> CommandRound:
        """Send ``verb`` to the flying ones of ``ids`` until each acknowledged it or reports one of
        the ``took_effect`` phases (mrswarm/run/command_round.py), supervising and showing the progress."""
        assert self.observer is not None
        ids = [u for u in ids if u in self._active_ids() and u not in self.rejoin]

        def show(r: CommandRound) -> None:
            done = len(r.targets) - len(r.missing) - len(r.gone)
            self.progress.detail = f"{verb}: {done}/{len(r.targets) - len(r.gone)} acknowledged ({plural(r.sends, 'send')})"
            self.display.refresh(self.observer)

        def tick() -> None:
            self.signals.check()
            self._supervise()
            if self.leader is not None:
                self._step_clock()

        r = command_round(self.observer, verb, ids, command_deadline(len(ids)), progress=show, clock=self.now,
                          took_effect=lambda u: self._phase_of(u) in took_effect, tick=tick, active=self._active_ids,
                          tick_advances=self.leader is not None)
        if r.refused:
            raise RunAborted(f"'{verb}' refused by {r.refused}")
        if r.missing and not self._go_on_without(r.missing, verb, len(ids)):
            raise RunAborted(f"no acknowledgement of '{verb}' from UAVs {r.missing} within {command_deadline(len(ids)):.0f} s "
                             f"({r.sends} sends)")
        n_acked = len(ids) - len(r.gone) - len(r.missing)
        who = f"all {n_acked}" if not r.missing else f"{n_acked} of {n_acked + len(r.missing)}"
        self.progress.reached(f"{verb} acknowledged by {who} in {1000 * (r.duration or 0.0):.0f} ms ({plural(r.sends, 'send')})")
        return r

    def _wait_phase(self, ids: list[int], phases: set[AgentPhase], timeout: float, stall: float | None = None,
                    cap: float | None = None, own: dict[int, float] | None = None) -> None:
        """Poll until every flying UAV of ``ids`` reports one of ``phases``; RunAborted after ``timeout`` s.

        With ``stall`` (s), the wait goes on past ``timeout`` while more UAVs keep reaching the
        phases, until none has for ``stall`` s, and never past ``cap`` s: on a loaded machine a
        large swarm gets ready slowly but surely, a stuck one is still given up on. ``own``: UAVs
        with a wait of their own (s from now; the external ones), which the others' deadline does not end."""
        own = own or {}
        ids = [u for u in ids if u not in self.rejoin]  # late ones join when they are ready (_rejoin_tick)
        t0 = self.now()
        deadline = t0 + timeout
        hard = t0 + max(timeout, cap if cap is not None else timeout)
        best = 0
        while True:
            now = self.now()
            active = [u for u in ids if u in self._active_ids()]
            behind = [u for u in active if self._phase_of(u) not in phases]
            if active and not behind:
                return
            late = [u for u in behind if (now >= deadline if u not in own else now >= t0 + own[u])]
            if late:
                break
            there = len(active) - len(behind)
            if stall is not None and there > best:  # progress: allow another ``stall`` s from now
                best = there
                deadline = min(max(deadline, now + stall), hard)
            waiting = [u for u in behind if u in own]
            if waiting:
                u = waiting[0]
                self.progress.detail = f"{there}/{len(active)} {'/'.join(sorted(phases))}; UAV {u} ({self._external_what(u)}): " \
                                       f"{max(0.0, t0 + own[u] - now):.0f} s left"
            self._tick()
        if self._go_on_without([u for u in active if self._phase_of(u) not in phases], "/".join(sorted(phases)), len(active),
                               external=set(own)):
            return
        behind = [u for u in ids if self._phase_of(u) not in phases]
        said = {u: str(self._phase_of(u) or "?") for u in behind}
        why = "".join(f"; UAV {u} ({self._external_what(u)}): {self._external_hint(u)}" for u in behind if u in own)
        raise RunAborted(f"timed out after {self.now() - t0:.0f} s waiting for {'/'.join(sorted(phases))}; still: {said}{why}")

    # ---- UAVs whose flight controller is external (docs/scenarios.md, "Physical and external UAVs") ------------------
    def _start_external(self, cfg: AgentConfig) -> None:
        """Its agent: a process on this machine against its flight controller (``agent: runner``), or
        its configuration written for its companion computer, whose agent the run waits for."""
        u = next(u for u in self.scn.external_uavs() if u.id == cfg.uav)
        home = self.scn.start_geodetic(u)
        where = f"its start ({u.start[0]:g}, {u.start[1]:g}) is {home.lat:.6f},{home.lon:.6f},{home.alt:g}"
        if u.agent == "runner":
            self.runtime.start_agent(cfg)
            self._say(f"UAV {u.id}: agent against the external flight controller {u.fcu} (realm {u.realm}; {where}); "
                      f"log: {self.run_dir / 'logs' / f'uav{u.id}.log'}")
            return
        self._companion_config(cfg)
        self._say(f"UAV {u.id}: its agent runs on its companion computer ({where}). Waiting up to {u.wait_s:g} s for it; "
                  f"start it there with:\n    {self._companion_command(u.id)}")

    def _companion_config(self, cfg: AgentConfig) -> Path:
        """``<run>/config/uav<N>.json``, the configuration ``mrswarm agent --config`` reads on the companion (0600: it
        holds the discovery key)."""
        path = self.run_dir / "config" / f"uav{cfg.uav}.json"
        path.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(path, cfg.to_json(), fsync=True, private=True)
        return path

    def _companion_command(self, uav: int) -> str:
        """The command line that starts a companion's agent with the configuration this run wrote for it."""
        insecure = " --insecure" if not self.scn.network.secured.enabled else ""
        return f"mrswarm agent --config {self.run_dir / 'config' / f'uav{uav}.json'}{insecure}"

    def _external_what(self, uav: int) -> str:
        u = next((u for u in self.scn.external_uavs() if u.id == uav), None)
        if u is None:
            return "virtual"
        return f"external FCU {u.fcu}" if u.agent == "runner" else "agent on its companion computer"

    def _external_hint(self, uav: int) -> str:
        """What to do about an external UAV that is late: what its agent says, and where to look."""
        u = next(u for u in self.scn.external_uavs() if u.id == uav)
        v = self.observer.uavs.get(uav) if self.observer is not None else None
        if v is None or v.state is None:
            if u.agent == "companion":
                return (f"its agent never joined the swarm: start `{self._companion_command(uav)}` on its companion "
                        f"computer, or raise uavs[].wait_s ({u.wait_s:g} s)")
            return f"its agent never joined the swarm (see {self.run_dir / 'logs' / f'uav{uav}.log'})"
        said = f"its agent says {v.state.detail!r}" if v.state.detail else f"its agent is in {v.state.phase}"
        where = f"see {self.run_dir / 'logs' / f'uav{uav}.log'}" if u.agent == "runner" else "see its log on the companion"
        return f"{said} ({where}; uavs[].wait_s is {u.wait_s:g} s)"

    def _land_external(self) -> None:
        """Before their agents stop: every external UAV off the ground is sent ``land`` (again every
        :data:`LAND_RESEND_S` s until its phase shows it), and the run waits until each is down, at
        most the mission altitude at :data:`LAND_SPEED` plus :data:`LAND_MARGIN_S`. A second stop
        signal ends the wait; a UAV still up then is left to its autopilot's own failsafe."""
        obs = self.observer
        flying = [u.id for u in self.scn.external_uavs() if u.id in self.ids and u.id not in self.lost]
        if obs is None or not flying or self.signals.fast:
            return
        obs.poll()
        up = [u for u in flying if self._phase_of(u) is not None and self._phase_of(u) not in ON_GROUND]
        if not up:
            return
        self.progress.stage = RunStage.STOPPING
        self._say(f"landing UAV{'s' if len(up) > 1 else ''} {', '.join(map(str, up))} (external flight controller) before "
                  "stopping" + (" (stop again to skip)" if self.signals.requested else ""))
        t0 = time.time()  # (external UAVs fly on the wall clock: lock-step refuses them)
        deadline = t0 + self.scn.flight.altitude / LAND_SPEED + LAND_MARGIN_S
        sent: dict[int, float] = {}
        while up and time.time() < deadline and not self.signals.fast:
            now = time.time()
            resend = [u for u in up if self._phase_of(u) not in (AgentPhase.LANDING, AgentPhase.LANDED)
                      and now - sent.get(u, 0.0) >= LAND_RESEND_S]
            if resend:
                obs.command("land", resend)
                sent.update({u: now for u in resend})
            time.sleep(TICK)
            obs.poll()
            up = [u for u in up if self._phase_of(u) not in ON_GROUND]
            self.progress.detail = f"landing {len(up)} external UAV(s), {deadline - time.time():.0f} s left"
            try:
                self.display.refresh(obs)
            except OSError:
                self.console.quiet = True
        if up:
            self._say(f"[yellow]UAV{'s' if len(up) > 1 else ''} {', '.join(map(str, up))} not on the ground after "
                      f"{time.time() - t0:.0f} s ({', '.join(str(self._phase_of(u)) for u in up)}): its autopilot's own "
                      "failsafe takes over once its agent stops[/]")
        else:
            self._say(f"external UAVs on the ground after {time.time() - t0:.0f} s")

    def _tick(self, look: float = TICK) -> None:
        """One poll of the swarm: stop signals, live metrics, process events, rejoins, the display, then TICK s of
        sleep (lock-step: ``look`` s of simulated time; the mission loop looks every LOCKSTEP_LOOK_S, the waits for
        a phase every TICK, as in real time, so that the takeoff and the start come when they would)."""
        assert self.observer is not None
        self.signals.check()
        if self.signals.hangup:
            self.console.quiet = True
        fresh = self.observer.poll()
        self.metrics.add_poses(self.observer, fresh)
        self.metrics.update_separation(self.observer)
        self._supervise()
        self._watch_stalls()
        self._rejoin_tick()
        try:
            self.display.refresh(self.observer)
        except OSError:  # the terminal is gone
            self.console.quiet = True
        if self.leader is None:
            time.sleep(TICK)
        else:
            self._step_clock(look)

    def _step_clock(self, seconds: float = TICK) -> None:
        """Lock-step time: ``seconds`` of simulated time, as fast as the pools run them (a pool whose process
        is gone, all its UAVs lost, is not waited for: the others fly on)."""
        assert self.leader is not None
        numbers = {int(name.removeprefix("pool")): uavs for name, uavs in self.run_info.pools.items()}
        gone = [k for k, uavs in numbers.items() if k in self.leader.pools and uavs and set(uavs) <= self.lost]
        if gone:
            self.leader.drop(gone)
            self._say(f"[yellow]lock-step time goes on without pool(s) {format_ids(gone)}[/] (their process exited)")
            if not self.leader.pools:
                raise RunAborted("lock-step time: every pool has exited")
        try:
            self.leader.advance(seconds)
        except LockstepStalled as exc:
            raise RunAborted(f"lock-step time stalled: {exc}") from None

    def _supervise(self) -> None:
        """Process exits and restarts become events (mrswarm/run/supervisor.py); the run goes on."""
        assert self.supervisor is not None
        events = self.supervisor.check()
        resumed = self.recorder.poll_resumed() if self.recorder is not None else None
        if resumed is not None:  # a restarted recorder records again: the end of the recording's gap
            ev = ProcessEvent(t=time.time(), name=RECORDER, event="resumed", detail=Path(resumed).name,
                              recorded_until=self.recorder.previous_flushed)  # type: ignore[union-attr]
            self.supervisor.events.append(ev)
            events.append(ev)
            self.run_info.recording_files = list(self.recorder.files)  # type: ignore[union-attr]
        for ev in events:
            self._on_event(ev)
        if events:
            self._save_info()
        if self.ids and not self._active_ids() and not self.rejoin and not any(
                self.supervisor.restarting(f"uav{u}") for u in self.lost):
            raise RunAborted(f"every UAV process has exited (see {self.run_dir / 'logs'})")

    def _watch_stalls(self, final: bool = False) -> None:
        """Flying UAVs whose poses stopped while their process lives: an event when the stall ends (or the run does)."""
        assert self.observer is not None and self.supervisor is not None
        now = self.now()
        began: list[int] = []
        if final:
            ended = self.stalls.close(now)
        else:
            last = {u: v.pose_recv for u, v in self.observer.uavs.items()}
            # the runner's own view: a client of the edge router sees nothing while its link to that router is down
            path: float | None = None  # a discovery peer: the other UAVs it hears vouch for its view
            if getattr(self.observer.node.connectivity, "mode", "") == "client":
                self._linked_since = (self._linked_since or now) if self.observer.node.routers() else None
                path = self._linked_since if self._linked_since is not None else math.inf
            began, ended = self.stalls.tick(now, last, set(self._active_ids()), path)
        for uav in began:
            self._say(f"[yellow]uav{uav} stalled[/]: no pose for {self.stalls.after:g} s, its process still runs")
        for ev in ended:
            self._say(f"[yellow]{ev.name} stalled[/] for {ev.duration_s:.1f} s")
            self.supervisor.events.append(ev)
        if ended:
            self._save_info()

    def _on_event(self, ev: ProcessEvent) -> None:
        uav = uav_of(ev.name)
        if ev.event == "exited":
            why = ev.signal or f"exit code {ev.exit_code}"
            where = f" at {ev.last_pose}" if ev.last_pose else ""
            self._say(f"[yellow]{ev.name} exited ({why}){where}[/]" + (f": {escape(ev.error)}" if ev.error else "")
                      + (f"; {ev.detail}" if ev.detail else ""))
            if uav is not None:
                self.lost.add(uav)
                self.rejoin.pop(uav, None)
        elif ev.event == "resumed":
            self._say(f"[green]{ev.name} recording again[/] into {ev.detail}")
        elif ev.event == "restarted":
            self._say(f"[green]{ev.name} started again[/] ({ev.detail})")
            if uav is not None:
                self.lost.discard(uav)
                self.rejoin[uav] = (ev.t, 0.0)
        else:
            self._say(f"[yellow]{ev.name}: {ev.event}[/] {ev.detail}")

    def _go_on_without(self, late: list[int], stage: str, of: int, external: set[int] | None = None) -> bool:
        """Go on without a few virtual UAVs that are late at ``stage`` (at most LATE_MAX_FRACTION of
        the ``of`` UAVs; none of them external): recorded as late, sent the command again until
        they fly with the others. False: too many, or an external one (the run gives up)."""
        if not late or len(late) > int(LATE_MAX_FRACTION * of) or set(late) & (external or set()) \
                or set(late) & {u.id for u in self.scn.external_uavs()}:
            return False
        now = self.now()
        for u in late:
            self.run_info.late.append(LateUav(uav=u, stage=stage, t=now))
            self.rejoin[u] = (0.0, now)  # any state it reports from now on
        self._say(f"[yellow]going on without {plural(len(late), 'late UAV')} ({format_ids(late)}, not {stage} in time)[/]: "
                  "each is sent the command again until it flies with the others")
        self._save_info()
        return True

    def _rejoin_tick(self) -> None:
        """A restarted UAV reports ready: send it start (takeoff before the mission), until it flies."""
        assert self.observer is not None
        now = self.now()
        for uav, (since, next_send) in list(self.rejoin.items()):
            v = self.observer.uavs.get(uav)
            if v is None or v.state is None or v.state_recv <= since:
                continue  # nothing from the new process yet
            phase = v.state.phase
            started = self.run_info.mission_start is not None
            if phase == AgentPhase.READY and now >= next_send:
                self.observer.command("start" if started else "takeoff", [uav])
                self.rejoin[uav] = (since, now + REJOIN_EVERY_S)
            elif phase not in (AgentPhase.INIT, AgentPhase.READY, AgentPhase.ARMING, AgentPhase.TAKEOFF, AgentPhase.OFFBOARD):
                del self.rejoin[uav]  # flying with the swarm again
                if phase == AgentPhase.HOVER and started:
                    self.observer.command("start", [uav])
