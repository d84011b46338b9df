"""Process entry points: a virtual UAV (virtual FCU + agent) and a standalone agent.

One single-threaded loop on a fixed tick (:func:`run_loop`) drives everything: the virtual
FCU's datagrams and physics (if any), the agent's MAVLink link, and the agent's step (which
drains the swarm node's inlets). Between ticks it sleeps on the node's waker, so a command is
handled as soon as it arrives. No asyncio: it would cost ~10 MB per process.
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import re
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Any, TypeVar

from groundfloor.process import die_with_parent, on_stop_signals, setup_logging
from groundfloor.schema import ConfigError, convert
from swarmnet.connectivity import Connectivity, Rendezvous, StaticPeers, TransportTuning, lean_zenoh_runtime, open_retrying
from swarmnet.messages import Realm
from swarmnet.node import NodeIdentity, SwarmNode
from swarmnet.security.identity import NodeName
from uav_stack import tick_meter
from uav_stack.agent import Agent
from uav_stack.cli_args import ArgumentParser
from uav_stack.config import AgentConfig, NetworkConfig, VirtualUavConfig, fcu_url_problem, pool_shares_session
from uav_stack.fcu_link import FcuLink, LinkOpenError
from uav_stack.inproc import InprocFcuSocket
from uav_stack.mavlink_router import MavlinkRouter, SigningPolicy
from uav_stack.mavlink_signing import SigningKeyError, read_key_file

if TYPE_CHECKING:  # imported at run time only where it is used (numpy-heavy)
    from swarmnet.shared_session import SharedSession
    from uav_stack.fcu import VirtualFcu

C = TypeVar("C")  # a process's configuration type (virtual_process_start)
log = logging.getLogger(__name__)

OPEN_TIMEOUT_S = 120.0  # s to keep trying to open the swarm node (a loaded router accepts late: 100 UAVs, ~2 min)
SHUTDOWN_WATCHDOG_S = 10  # s from a stop signal to the process ending, whatever hangs


class StopFlag:
    """Set by SIGTERM/SIGINT (and by the parent dying, via PR_SET_PDEATHSIG)."""

    def __init__(self) -> None:
        self.stopped = False

    def set(self, *_: object) -> None:
        self.stopped = True

    def install(self) -> StopFlag:
        on_stop_signals(self._on_signal)
        # no part of a UAV process uses signal-driven I/O, and SIGIO's default ends the process: the
        # lease the counters file takes (uav_stack.recorder.SwappedJsonFile) can raise one
        signal.signal(signal.SIGIO, signal.SIG_IGN)
        return self

    def _on_signal(self, signum: int, frame: FrameType | None) -> None:
        self.stopped = True
        # the records are written first thing on the way out; should closing the sessions then
        # hang, SIGALRM's default action ends the process (no orphan when the runner is gone)
        signal.alarm(SHUTDOWN_WATCHDOG_S)


def make_connectivity(net: NetworkConfig, name: NodeName | None = None) -> Connectivity:
    """The node's connectivity strategy; ``name`` is who it is, for credentials that do not say."""
    creds = net.security.for_node(name) if net.security is not None and name is not None else net.security
    tuning = TransportTuning(lease_ms=round(1000 * net.lease_s))
    if net.connectivity == "rendezvous":
        return Rendezvous(tuple(net.endpoints), mode=net.mode, listen=tuple(net.listen), tuning=tuning, credentials=creds)
    if net.connectivity == "static":
        return StaticPeers(tuple(net.endpoints), listen=tuple(net.listen), tuning=tuning, credentials=creds)
    if net.connectivity == "discovery":  # beacon relay through a discovery server (discovery/proxy.py)
        from discovery.proxy import BeaconDiscovery

        assert net.discovery is not None  # NetworkConfig requires it with this connectivity
        return BeaconDiscovery.from_options(net.discovery, listen=net.listen, connect=net.endpoints, credentials=creds,
                                            tuning=tuning)
    raise ValueError(f"unknown connectivity {net.connectivity!r}")


class SimTime:
    """Lock-step time as a clock: ``sim()`` is the simulated time (s since the Unix epoch) that the
    loop set last (:attr:`now`), for every part of a pool that reads a clock."""

    __slots__ = ("now",)

    def __init__(self, start: float):
        self.now = start

    def __call__(self) -> float:
        return self.now


def make_node(cfg: AgentConfig, shared: SharedSession | None = None, clock: Callable[[], float] = time.time) -> SwarmNode:
    """The agent's swarm node: a session of its own, or a member of a pool's ``shared`` one."""
    ident = NodeIdentity(cfg.swarm, cfg.uav, Realm.parse(cfg.realm), "uav")
    conn = make_connectivity(cfg.network, NodeName.uav(cfg.uav, cfg.swarm))
    return SwarmNode(ident, conn, pose_rate_hz=cfg.pose_rate_hz, stale_after=cfg.stale_after,
                     pose_feed=cfg.network.pose_feed, netem=cfg.network.netem, near_feed=cfg.network.interest is not None,
                     shared=shared, clock=clock)


def shares_session(net: NetworkConfig) -> bool:
    """Pooled UAVs on this network share their pool's one session (:func:`~uav_stack.config.pool_shares_session`)."""
    return pool_shares_session(net.connectivity)


def open_shared_session(cfgs: list[AgentConfig], number: int, stop: StopFlag,
                        timeout: float = OPEN_TIMEOUT_S, clock: Callable[[], float] = time.time,
                        lockstep: bool = False) -> SharedSession:
    """Pool ``number``'s one session for the UAVs of ``cfgs`` (one swarm, one network), opened: it
    speaks as ``pool-<number>``, whose certificate speaks for those UAVs (docs/security.md)."""
    from swarmnet.shared_session import SharedSession

    first = cfgs[0]
    net = first.network
    share = SharedSession(first.swarm, make_connectivity(net, NodeName("pool", number, first.swarm)), pose_feed=net.pose_feed,
                          stale_after=first.stale_after, name=f"pool {number}", number=number, interest=net.interest,
                          clock=clock, lossless=lockstep)
    if net.security is None:
        log.warning("plain TCP without access control (network.security: off): anyone who reaches this pool's "
                    "network can command its UAVs and speak for any UAV (docs/security.md)")
    return open_retrying(share.open, timeout, f"pool {number}", lambda: stop.stopped)


def open_node(cfg: AgentConfig, stop: StopFlag, tap_zenoh_log: bool = False, timeout: float = OPEN_TIMEOUT_S,
              shared: SharedSession | None = None, clock: Callable[[], float] = time.time) -> SwarmNode:
    """The agent's node, opened. A secured node in its own process (``tap_zenoh_log``) also counts
    the TLS handshakes its listener refuses (swarmnet/security/zenoh_log.py); an insecure one says
    at start that anyone on its network can command it.

    When a whole swarm starts at once on a loaded machine (100 UAV processes on 2 cores), the
    edge router can take longer than Zenoh's connect timeout to accept a client, and the session
    refuses to open: it is tried again until ``timeout`` s (swarmnet.connectivity.open_retrying).
    """
    node = make_node(cfg, shared, clock)
    if shared is not None:
        return node.open()  # (the shared session said it all when it opened)
    if cfg.network.security is None:
        log.warning("plain TCP without access control (network.security: off): anyone who reaches this node's "
                    "network can command it and speak for any UAV (docs/security.md)")
    elif tap_zenoh_log:
        from swarmnet.security.zenoh_log import ZenohLogTap

        ZenohLogTap(node.stats)
    return open_retrying(node.open, timeout, f"UAV {cfg.uav}", lambda: stop.stopped)


def signing_policy(cfg: AgentConfig) -> SigningPolicy:
    """What the router's ground-station endpoints accept (docs/security.md), said in the log when
    it is not "signed": commands signed with the swarm's MAVLink key, by default; without a key,
    telemetry only; every frame with ``gcs.allow_unsigned``. A key file that cannot be read
    (:func:`check_signing_key` said so at start; it went since) leaves the router telemetry only."""
    path = cfg.mavlink_key_file()
    key = None
    if path is not None:
        try:
            key = read_key_file(path)
        except SigningKeyError as exc:
            log.error("gcs.signing.key_file: %s", exc)
    policy = SigningPolicy(key, cfg.gcs.allow_unsigned)
    if not cfg.gcs.mavlink_endpoints:
        return policy
    if policy.allow_unsigned:
        log.warning("MAVLink: unsigned ground-station commands accepted (gcs.allow_unsigned): any process that reaches %s "
                    "can command this UAV (docs/security.md)", ", ".join(cfg.gcs.mavlink_endpoints))
    elif key is None:
        log.warning("MAVLink: no signing key (gcs.signing.key_file, or mavlink.key in the UAV's key directory): ground "
                    "stations get telemetry, and no command is accepted (docs/security.md)")
    return policy


def open_fcu_link(cfg: AgentConfig, url: str, target_system: int | None = None,
                  clock: Callable[[], float] = time.time) -> tuple[FcuLink, MavlinkRouter | None]:
    """The agent's FCU link and, if ground-station endpoints are configured, its MAVLink router
    (:func:`signing_policy`). ``target_system``: the FCU's sysid, if known; ``clock``: what stamps
    the FCU's messages (lock-step: simulated time; the router's ground stations keep the wall's).

    Raises :class:`~uav_stack.fcu_link.LinkOpenError`, naming the setting and the link, when a
    ground-station socket or the FCU link cannot be opened (a ``udpin`` port another process
    holds, a serial device that is not there)."""
    sysid = cfg.mavlink_sysid
    link = FcuLink(url, source_system=sysid, target_system=target_system, bind=cfg.fcu_bind, clock=clock)
    router = None
    if cfg.gcs.mavlink_endpoints:
        router = MavlinkRouter(cfg.gcs.mavlink_endpoints, link.write, own=(sysid, link.source_component),
                               bind=cfg.gcs.bind, signing=signing_policy(cfg)).open()
        link.on_message = router.from_fcu
    try:
        link.open()
    except BaseException:
        if router is not None:
            router.close()
        raise
    return link, router


def check_signing_key(cfg: AgentConfig, ap: argparse.ArgumentParser) -> None:
    """A MAVLink signing key file that cannot be used: a usage error naming the field, before anything starts."""
    path = cfg.mavlink_key_file()
    if cfg.gcs.mavlink_endpoints and path is not None:
        try:
            read_key_file(path)
        except SigningKeyError as exc:
            ap.error(f"gcs.signing.key_file: {exc}")


def tick_hz_for(cfg: AgentConfig) -> float:
    """The loop's ticks per second (Hz): the agent's fastest own rate, its control or its pose
    rate (10 Hz by default).

    Why not faster: nothing the agent does runs more often, and every tick costs the same fixed
    wake-up, socket reads and polls whether or not anything is due. A lone virtual UAV cost
    about a fifth less CPU at 10 Hz than at the former 25 Hz (docs/benchmarks.md). Commands do
    not wait for a tick (the loop wakes on them), and the FCU's physics keeps its own rate (its
    steps run in a batch per tick)."""
    return max(cfg.control_rate_hz, cfg.pose_rate_hz)


LATE_AFTER = 0.5  # of a period: a tick that begins this long after its time is late (the host did not keep up)


@dataclass
class LoopStats:
    """How a UAV process's loop kept its ticks: the counters file's ``loop`` section. Late ticks
    mean the machine could not keep up (the run's summary says so: ``saturated``)."""

    period_s: float = 0.1
    ticks: int = 0
    late: int = 0  # ticks that began more than LATE_AFTER of a period after their time
    worst_late_s: float = 0.0
    # lock-step time (a pool stepped by the run's leader), summed over its steps: wall s from a step's
    # arrival to the pool's answer, the loop thread's CPU s in them, and wall s from an answer to the next step
    steps: int = 0
    work_s: float = 0.0
    cpu_s: float = 0.0
    wait_s: float = 0.0
    waits: int = 0  # steps after an answer (the first step has no wait before it)

    def tick(self, late_s: float) -> None:
        self.ticks += 1
        if late_s > LATE_AFTER * self.period_s:
            self.late += 1
            self.worst_late_s = max(self.worst_late_s, late_s)

    def step(self, work_s: float, cpu_s: float, wait_s: float | None) -> None:
        """A lock-step step ran: ``work_s`` wall s (``cpu_s`` of the loop thread's CPU), after ``wait_s`` wall s
        of waiting for it since the last answer (None: the first step, nothing answered before it)."""
        self.steps += 1
        self.work_s += work_s
        self.cpu_s += cpu_s
        if wait_s is not None:
            self.waits += 1
            self.wait_s += wait_s

    def as_dict(self) -> dict[str, object]:
        out: dict[str, object] = {"period_s": self.period_s, "ticks": self.ticks, "late": self.late,
                                  "worst_late_s": round(self.worst_late_s, 3)}
        if self.steps:  # per step, ms: where a lock-step tick's wall time goes (docs/campaigns.md)
            n = self.steps
            out["lockstep"] = {"steps": n, "work_ms": round(1000.0 * self.work_s / n, 3),
                               "cpu_ms": round(1000.0 * self.cpu_s / n, 3),
                               "wait_ms": round(1000.0 * self.wait_s / self.waits, 3) if self.waits else 0.0}
        return out


def run_loop(agent: Agent, stop: StopFlag, fcu: VirtualFcu | None = None, duration: float | None = None,
             tick_hz: float | None = None) -> None:
    """Drive the FCU (optional) and the agent on one fixed tick until stopped.

    One wake-up per tick (``tick_hz``, default :func:`tick_hz_for` the agent's configuration)
    does everything: the FCU's datagrams and physics (run in a batch of fixed sim steps, up
    to now), then the agent's step (MAVLink in, Zenoh in and out, control), then the FCU's
    datagrams once more, so the setpoints the agent has just sent apply from now on, as over a
    real serial link (within a millisecond), rather than a tick later. Fewer, fuller ticks are
    cheaper than waking on every datagram and timer: with other processes evicting the CPU
    caches between ticks, each code path costs several times its warm cost
    (docs/benchmarks.md).

    Between ticks the loop waits on the swarm node's waker rather than sleeping: a command
    (or a netem change) wakes it, and :meth:`Agent.react` handles it at once. Poses do not
    wake it: they wait, stamped with their arrival, for the next tick's control.

    With ``align_ticks`` in the agent's configuration the ticks fall on the wall clock's grid,
    every UAV's at the same instants, each tick in two halves (:func:`_run_aligned`).
    """
    parent = os.getppid()
    period = 1.0 / (tick_hz or tick_hz_for(agent.cfg))
    loop = LoopStats(period)
    agent.stats_sources["loop"] = loop.as_dict
    t0 = time.monotonic()
    end = math.inf if duration is None else t0 + duration
    if agent.cfg.align_ticks:
        _run_aligned(agent, stop, fcu, period, end, parent, loop)
        return
    next_tick = t0
    while not stop.stopped:
        now_m = time.monotonic()
        if now_m >= end:
            break
        if next_tick > now_m:
            if agent.node.waker.wait(min(next_tick, end) - now_m):
                agent.react(time.time())
            continue
        loop.tick(now_m - next_tick)
        next_tick = max(next_tick + period, now_m)  # late: skip, never burst
        if fcu is not None:
            fcu.poll_io()
            fcu.service()
        agent.step(time.time())
        if fcu is not None:
            fcu.poll_io()  # the setpoints and commands just sent: applied now, not a tick later
        if os.getppid() != parent:  # re-parented: the launcher is gone
            break


# Aligned ticks: the latest the control waits for the poses a netem shim holds back, in periods
# after the instant (then it acts on those it has; the rest are used a tick later).
LATEST_ACT = 0.9
# Aligned ticks: the virtual FCU's steps fall this long (s) before the grid's instants, so that the
# step of an instant is always due when the loop wakes for it (the clocks differ by microseconds).
FCU_LEAD_S = 0.001


def next_grid_instant(now_m: float, period: float) -> float:
    """The monotonic time (s) of the wall clock's next grid instant after ``now_m``: the next
    whole multiple of ``period`` s since the Unix epoch. A wake-up a hair before its instant (the
    two clocks' readings differ by microseconds) belongs to that instant: the one after is
    returned, not a second tick right after it."""
    to_next = period - (time.time() % period)
    return now_m + (to_next if to_next > 0.1 * period else to_next + period)


def _run_aligned(agent: Agent, stop: StopFlag, fcu: VirtualFcu | None, period: float, end: float, parent: int,
                 loop: LoopStats) -> None:
    """:func:`run_loop` on the wall clock's grid: each tick in two halves, sense then act.

    At each instant of the grid (whole multiples of ``period`` s since the Unix epoch, found
    again every tick, so that a step of the wall clock moves the grid, never bursts it) the FCU
    and :meth:`Agent.sense`: the own pose leaves, as every other UAV's does at that instant.
    Then :meth:`Agent.act`: the control sees the others' poses of that instant rather than
    those of the instant before. It acts as soon as they have arrived, one from each neighbour
    heard at the instant before, directly or in the edge feed's batches
    (:meth:`SwarmNode.expect_poses`; through a netem shim, when the shim releases the last of
    them, up to :data:`LATEST_ACT` of a period), half a period after the instant at the latest
    (a pose lost, or a loaded machine's tens of ms). With spatial interest on the edge feed it
    cannot tell, and acts half a period after the instant. A UAV that heard nobody runs the
    whole tick at once. A late half runs at once; instants missed by a loop late more than a
    period are not made up.
    """
    node = agent.node
    next_sense = next_grid_instant(time.monotonic(), period)
    instant = next_act = math.inf
    while not stop.stopped:
        now_m = time.monotonic()
        if now_m >= end:
            break
        due = min(next_sense, next_act)
        if due > now_m:
            if node.waker.wait(min(due, end) - now_m):
                if next_act < math.inf and node.expected_poses_in():  # the instant's poses have arrived
                    node.stop_expecting_poses()
                    next_act = now_m  # act now: it takes them in, and any command
                    if node.netem is not None:  # unless the shim holds them: act when it releases the last,
                        agent.react(time.time())  # even past half a period (an LTE profile's 50 ms)
                        due_wall = node.expected_poses_due()
                        if due_wall is not None:
                            next_act = min(instant + LATEST_ACT * period,
                                           time.monotonic() + max(due_wall - time.time(), 0.0))
                else:
                    agent.react(time.time())
            continue
        if next_act <= next_sense:  # the act of the last instant first, even when late
            next_act = math.inf
            node.stop_expecting_poses()
            if fcu is not None:
                fcu.poll_io()
            agent.act(time.time())
            if fcu is not None:
                fcu.poll_io()  # the setpoints just sent: applied now
            continue
        instant = next_sense
        loop.tick(now_m - instant)
        next_sense = next_grid_instant(now_m, period)
        instant = max(instant, next_sense - period)  # its own instant, unless more than a period late
        # nobody to wait for (a lone UAV): the whole tick in this wake-up, as run_loop does it
        whole = node.expect_poses(time.time() - (now_m - instant)) == 0  # (the instant's wall time)
        if not whole:
            next_act = instant + 0.5 * period
        if fcu is not None:
            fcu.poll_io()
            fcu.service()
        (agent.step if whole else agent.sense)(time.time())
        if fcu is not None:
            fcu.poll_io()
        if os.getppid() != parent:  # re-parented: the launcher is gone
            break


# What a ground station's map and instruments read, at the rates the virtual FCU once sent unasked: a virtual
# PX4 UAV with a MAVLink endpoint keeps these on its link beside the agent's own (a ground station may ask
# for more with SET_MESSAGE_INTERVAL)
GCS_VIEW_HZ = {"ATTITUDE": 5.0, "VFR_HUD": 2.0, "LOCAL_POSITION_NED": 2.0, "BATTERY_STATUS": 0.5,
               "SYSTEM_TIME": 1.0, "MISSION_CURRENT": 1.0}


def virtual_stream_rates(cfg: VirtualUavConfig) -> dict[str, float]:
    """The virtual FCU's streams, set up as a companion sets a real PX4's onboard link when it reads few of its
    400 messages a second (SET_MESSAGE_INTERVAL -1 for the rest): the ones its agent asks for (the start-up
    contract's), and a ground station's view if the UAV has a MAVLink endpoint. A virtual ArduPilot stays as
    its firmware boots, silent until asked (its agent and ground stations ask)."""
    if cfg.flavour != "px4":
        return {}
    from uav_stack.autopilot import PX4_PROFILE
    from uav_stack.fcu.streams import turned_down
    from uav_stack.fcu_contract import wants_for

    a = cfg.agent
    wanted = {w.name: w.hz for w in wants_for(PX4_PROFILE, a.pose_rate_hz)}
    if a.gcs.mavlink_endpoints:
        wanted = {**GCS_VIEW_HZ, **wanted}
    return turned_down(cfg.flavour, wanted)


def make_virtual_fcu(cfgs: list[VirtualUavConfig], start: float | None = None, inproc: bool = False,
                     clock: Callable[[], float] | None = None, heartbeat_offset_s: float = 0.0) -> VirtualFcu:
    """One virtual FCU for these virtual UAVs (one vehicle each, stepped together), opened: one
    UDP socket per vehicle on the loopback, or with ``inproc`` (a pool: every agent in this
    process) an in-process channel per vehicle (:mod:`uav_stack.inproc`). They share its physics
    rate and target RTF (the first's); its streams are the first's flavour's, with a ground
    station's view if any has a MAVLink endpoint. ``heartbeat_offset_s``: :attr:`FcuConfig.heartbeat_offset_s`."""
    from uav_stack.fcu import FcuConfig, VehicleConfig, VirtualFcu  # numpy-heavy, only here

    first = cfgs[0]
    rates = virtual_stream_rates(next((c for c in cfgs if c.agent.gcs.mavlink_endpoints), first))
    fcu = VirtualFcu(
        FcuConfig(
            vehicles=[VehicleConfig(sysid=c.agent.mavlink_sysid, home=c.home, flavour=c.flavour, yaw=c.heading, inproc=inproc)
                      for c in cfgs],
            stream_rates=rates,
            physics_hz=first.physics_hz,
            target_rtf=first.target_rtf,
            # the loop comes back once per tick: a tick's lateness beyond that drops sim time, not less
            max_catchup_s=FcuConfig.max_catchup_s + 1.0 / tick_hz_for(first.agent),
            heartbeat_offset_s=heartbeat_offset_s,
        ),
        **({} if clock is None else {"clock": clock}),  # lock-step: simulated time, the Unix clock's origin
    )
    fcu.open(start)
    if clock is not None:  # its GPS time: simulated too
        fcu.ctx.unix_at_start = clock() if start is None else start
    return fcu


@dataclass
class VirtualUav:
    """One virtual UAV's parts in a process: its agent (with its node, its FCU link and its router)
    and the faults of its vehicle of the virtual FCU."""

    agent: Agent
    faults: Any  # uav_stack.sim_faults.SimFaults

    def close(self) -> None:
        a = self.agent
        a.close(time.time())
        a.node.close()
        a.link.close()
        if a.router is not None:
            a.router.close()


def open_virtual_uav(cfg: VirtualUavConfig, fcu: VirtualFcu, index: int, stop: StopFlag,
                     tap_zenoh_log: bool = False, shared: SharedSession | None = None,
                     clock: Callable[[], float] = time.time) -> VirtualUav:
    """The agent of the FCU's vehicle ``index``: its FCU link (the vehicle's only client: over UDP,
    or the vehicle's in-process channel), its swarm node (a member of a pool's ``shared`` session,
    if given), its faults. :class:`LinkOpenError` if the link cannot open."""
    a = cfg.agent
    link, router = open_fcu_link(a, fcu.vehicles[index].link.url, target_system=a.mavlink_sysid, clock=clock)
    # the agent is its FCU's only client (ground stations come through its router): nobody
    # else's datagrams reach the FCU, nor churn the agent out of its peers
    assert link.local_address is not None
    fcu.vehicles[index].link.set_owner(link.local_address, owner_only=True)
    try:
        node = open_node(a, stop, tap_zenoh_log, shared=shared, clock=clock)
    except BaseException:
        link.close()
        if router is not None:
            router.close()
        raise
    agent = Agent(a, node, link, router=router)
    agent.stats_sources["virtual_fcu"] = fcu.stats.as_dict  # its counters (refused datagrams too) in uav<N>.json
    if isinstance(link.udp, InprocFcuSocket):  # what the in-process link carried and dropped, each way
        agent.stats_sources["fcu_inproc"] = link.udp.channel.as_dict
    return VirtualUav(agent, attach_sim_faults(agent, fcu, a.seed * 1_000_003 + a.uav, index))


def run_virtual_uav(cfg: VirtualUavConfig, stop: StopFlag, tap_zenoh_log: bool = False) -> int:
    a = cfg.agent
    start = None
    if a.align_ticks:  # the FCU's 10 Hz position on the ticks' grid, a hair before each instant: the
        period = 1.0 / tick_hz_for(a)  # pose that leaves at an instant is the position of that instant
        start = time.monotonic() - (time.time() % period) - FCU_LEAD_S
    fcu = make_virtual_fcu([cfg], start)
    try:
        uav = open_virtual_uav(cfg, fcu, 0, stop, tap_zenoh_log)
    except LinkOpenError as exc:
        log.error("%s", exc)
        fcu.close()
        return 2
    meter = tick_meter.attach(uav.agent, fcu)  # None unless the environment asks for it
    try:
        run_loop(uav.agent, stop, uav.faults, cfg.duration)
    finally:
        if meter is not None:
            meter.write(f"tick_uav{a.uav}.json")
        uav.close()
        fcu.close()
    return 0


def attach_sim_faults(agent: Agent, fcu: Any, seed: int, index: int = 0) -> Any:
    """Let the experiment controller inject faults into this virtual UAV (uav_stack/sim_faults.py), and
    record the FCU's ground truth, which a falsified position estimate does not change. Returns the
    faults of the FCU's vehicle ``index``, which wrap the FCU for :func:`run_loop`."""
    from uav_stack.sim_faults import SimFaults

    faults = SimFaults(fcu, seed, index)
    agent.fault_handler = faults.apply
    v, dyn = fcu.vehicles[index], fcu.dyn
    o = v.frame.origin  # the FCU's local NED origin (its first home)
    hx, hy, hz = agent.frame.to_enu(o.lat, o.lon, o.alt)

    def truth() -> tuple[float, float, float, float, float, float, bool]:
        (n, e, d), (vn, ve, vd) = dyn.pos[v.i].tolist(), dyn.vel[v.i].tolist()
        k = agent.link.rtf.value
        k = k if 0.0 < k < 1.0 else 1.0  # wall-clock velocities, as the agent publishes them
        return hx + e, hy + n, hz - d, ve * k, vn * k, -vd * k, v.armed

    agent.truth = truth
    return faults


def run_agent(cfg: AgentConfig, stop: StopFlag, duration: float | None = None, tap_zenoh_log: bool = False) -> int:
    try:
        link, router = open_fcu_link(cfg, cfg.fcu)
    except LinkOpenError as exc:
        log.error("%s", exc)
        return 2
    import zenoh

    try:
        node = open_node(cfg, stop, tap_zenoh_log)
    except zenoh.ZError as exc:  # the swarm unreachable for OPEN_TIMEOUT_S, or refused: one line, not a traceback
        link.close()
        if router is not None:
            router.close()
        if stop.stopped:
            return 0
        net = cfg.network
        via = f"the discovery server {net.discovery.server}" if net.discovery is not None else ", ".join(net.endpoints)
        log.error("network: cannot join swarm %r through %s: %s", cfg.swarm, via, str(exc).splitlines()[0] if str(exc) else exc)
        return 1
    agent = Agent(cfg, node, link, router=router)
    try:
        run_loop(agent, stop, None, duration)
    finally:
        agent.close(time.time())
        node.close()
        link.close()
        if router is not None:
            router.close()
    return 0


def virtual_process_start(prog: str, description: str, load: Callable[[str], C],
                          argv: list[str] | None = None) -> tuple[C, StopFlag, argparse.ArgumentParser]:
    """The start of a process the runtime launches with ``--config FILE`` (one virtual UAV, or a
    pool): its arguments, death with its parent, a lean Zenoh runtime, stop signals, logging, and
    the configuration ``load`` reads (a bad file: a usage error naming it). Returns the parser too,
    for the caller's own checks of the configuration."""
    ap = argparse.ArgumentParser(prog=prog, description=description)
    ap.add_argument("--config", required=True, help="JSON written by the runner")
    ap.add_argument("--log-level", default="INFO")
    ap.add_argument("--log-file", default=None)
    args = ap.parse_args(argv)
    die_with_parent()
    lean_zenoh_runtime()
    stop = StopFlag().install()
    setup_logging(args.log_level, args.log_file)
    try:
        cfg = load(args.config)
    except (ConfigError, OSError) as exc:
        ap.error(f"{args.config}: {exc}")
    return cfg, stop, ap


def virtual_uav_main(argv: list[str] | None = None) -> int:
    """``python -m uav_stack.virtual_uav --config uav3.json``: what the process runtime launches."""
    cfg, stop, ap = virtual_process_start("python -m uav_stack.virtual_uav",
                                          "one virtual UAV: virtual FCU + agent, in one process", VirtualUavConfig.load, argv)
    check_signing_key(cfg.agent, ap)
    return run_virtual_uav(cfg, stop, tap_zenoh_log=True)


# `mrswarm agent`'s flags beside --config: the ones a companion computer's own setup gives (where
# its flight controller, its credentials and its records are), replacing the file's
WITH_CONFIG = ("fcu", "keys", "identity", "record_dir", "insecure", "duration", "log_level", "behaviour", "params")
# where a field of the agent's configuration comes from on the command line, to name it in an error
FLAG_OF = {"fcu_bind": "--fcu-bind", "fcu": "--fcu", "swarm": "--swarm", "uav": "--uav", "origin": "--origin",
           "realm": "--realm", "record_dir": "--record-dir", "avoidance.zones": "--zones",
           "network.endpoints": "--connect", "network.listen": "--listen", "network.mode": "--mode",
           "network.pose_feed": "--pose-feed", "network.discovery.server": "--discovery",
           "network.discovery.key_file": "--discovery-key-file", "network.discovery.advertise": "--advertise",
           "network.discovery": "--discovery", "network.security.identity": "--identity", "network.security": "--keys",
           "gcs.mavlink_endpoints": "--mavlink-endpoint", "gcs.bind": "--mavlink-bind",
           "gcs.signing.key_file": "--mavlink-key-file", "gcs.sysid": "--sysid"}


# a Zenoh endpoint as the agent takes it: <protocol>/<address>, the address a HOST:PORT (IPv6 in brackets)
ZENOH_ENDPOINT = re.compile(r"^(tcp|tls|udp|quic|ws|wss)/(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.\-]+):\d{1,5}([?#]\S*)?$")


def _flags(dests: tuple[str, ...]) -> str:
    return ", ".join("--" + d.replace("_", "-") for d in dests)


def agent_parser() -> argparse.ArgumentParser:
    ap = ArgumentParser(prog="mrswarm agent", description="run the swarm agent against any MAVLink flight controller")
    ap.add_argument("--fcu", default=None,
                    help="pymavlink connection string: serial:/dev/ttyACM0:921600, udpin:127.0.0.1:14540, tcp:... (required)")
    ap.add_argument("--fcu-bind", default=None, metavar="ADDR",
                    help="local address of a udpout FCU link (default: the one that routes to the FCU)")
    ap.add_argument("--swarm", default=None, help="the swarm's name (required)")
    ap.add_argument("--uav", type=int, default=None, help="this UAV's id (1..65535; required)")
    ap.add_argument("--origin", default=None, metavar="LAT,LON,ALT",
                    help="swarm origin: degrees, degrees, m AMSL, e.g. --origin -35.36,149.16,584 (required)")
    ap.add_argument("--realm", default="physical", choices=["physical", "virtual"])
    ap.add_argument("--connect", action="append", default=[], help="Zenoh endpoint of the rendezvous/edge router (repeatable)")
    ap.add_argument("--mode", default="peer", choices=["peer", "client"], help="client behind carrier NAT")
    ap.add_argument("--pose-feed", default="direct", choices=["direct", "edge"],
                    help="edge: receive neighbour poses as batches from the edge router's feed")
    ap.add_argument("--listen", action="append", default=None,
                    help="Zenoh listen endpoint (peer mode; default tcp/127.0.0.1:0: a UAV on a network names its own address)")
    ap.add_argument("--discovery", default=None, metavar="HOST:PORT",
                    help="find the swarm through this discovery server (instead of --connect's router)")
    ap.add_argument("--discovery-key-file", default=None, help="the swarm's discovery key (mrswarm discovery keygen)")
    ap.add_argument("--advertise", action="append", default=[], help="announce this address/locator to peers (public IP)")
    ap.add_argument("--keys", default=None, metavar="DIR",
                    help="this UAV's credentials: its bundle from `mrswarm keys bundle uav-<id>` (CA, roster, its certificate)")
    ap.add_argument("--identity", default=None, help="certificate to speak as (default: uav-<id>.<swarm>)")
    ap.add_argument("--insecure", action="store_true",
                    help="plain TCP without access control: anyone on the network can command this UAV (labs only)")
    ap.add_argument("--config", default=None, metavar="FILE",
                    help="JSON AgentConfig with the mission etc., as `mrswarm run` writes it for a companion computer; "
                         f"only {_flags(WITH_CONFIG)} go beside it (they replace the file's)")
    ap.add_argument("--autostart", action="store_true", help="take off and start the mission without waiting for 'start'")
    ap.add_argument("--record-dir", default=None, metavar="DIR",
                    help="write the trajectory and counters here (made if missing)")
    ap.add_argument("--mavlink-endpoint", action="append", default=[], metavar="udpout:HOST:PORT",
                    help="route the FCU's MAVLink to a ground station (udpout:HOST:14550 for QGC; udpin:HOST:PORT to listen);"
                         " repeatable")
    ap.add_argument("--mavlink-bind", default=None, metavar="ADDR",
                    help="local address of the udpout ground-station endpoints (default: the one that routes to each)")
    ap.add_argument("--mavlink-key-file", default=None, metavar="FILE",
                    help="the MAVLink signing passphrase: ground stations that sign with it may command (default: "
                         "mavlink.key in --keys; without one, telemetry only; `mrswarm keys mavlink` prints it)")
    ap.add_argument("--mavlink-allow-unsigned", action="store_true",
                    help="also route unsigned frames from ground stations (MAVSDK cannot sign): anyone who reaches "
                         "an endpoint can command this UAV")
    ap.add_argument("--sysid", type=int, default=0, help="MAVLink sysid of the FCU (default: from the UAV id, see docs/gcs.md)")
    ap.add_argument("--zones", default=None, metavar="FILE",
                    help="no-fly zones and obstacles to keep out of: a scenario (its world.zones) or a list of zones, "
                         "YAML or JSON (docs/world.md)")
    ap.add_argument("--behaviour", default=None, metavar="SPEC",
                    help="fly a behaviour of the SDK: package.module:Class or a registered name (docs/sdk.md); "
                         "its package installed on this computer")
    ap.add_argument("--params", default=None, metavar="JSON|@FILE",
                    help="the behaviour's parameters: a JSON object, or @FILE of YAML or JSON (default: its defaults)")
    ap.add_argument("--duration", type=float, default=None, help="stop after this many seconds (default: until signalled)")
    ap.add_argument("--log-level", default="INFO")
    return ap


def with_behaviour(cfg: AgentConfig, args: argparse.Namespace, ap: argparse.ArgumentParser) -> AgentConfig:
    """``--behaviour`` and ``--params`` into the mission, checked now (the class imported, the parameters
    validated): an error names the flag and the field."""
    if args.behaviour is None and args.params is None:
        return cfg
    from msgspec.structs import replace

    from uav_stack.sdk.sdk_flags import read_params

    spec = args.behaviour or cfg.mission.behaviour
    if spec is None:
        ap.error("--params: for a behaviour: give --behaviour SPEC too")
    try:
        params = read_params(args.params) if args.params is not None else (cfg.mission.params if args.behaviour is None else {})
    except ValueError as exc:
        ap.error(f"--params: {exc}")
    from uav_stack.sdk import loader

    try:
        loader.load(spec, params)
    except ConfigError as exc:
        flag = "--behaviour" if exc.path == "behaviour" else "--params"
        ap.error(f"{flag}: {exc.path.removeprefix('params.') + ': ' if exc.path.startswith('params.') else ''}{exc.msg}")
    return replace(cfg, mission=replace(cfg.mission, type="behaviour", behaviour=spec, params=params))


def parse_agent(argv: list[str] | None = None) -> tuple[AgentConfig, argparse.Namespace]:
    """The configuration ``mrswarm agent``'s command line describes, checked before anything starts.

    Every mistake is a usage error (exit 2) of one line naming the flag: a missing or malformed
    flag, no way to the swarm (neither ``--connect`` nor ``--discovery``), credentials or a key
    file that cannot be used, an FCU connection string that is not one. The folder of
    ``--record-dir`` is made if missing."""
    ap = agent_parser()
    args = ap.parse_args(argv)
    if args.config:
        given = [a for a in ap._actions if a.dest not in (*WITH_CONFIG, "config", "help")
                 and getattr(args, a.dest) != a.default]
        if given:
            ap.error(f"{given[0].option_strings[0]}: the --config file sets it (beside --config only {_flags(WITH_CONFIG)})")
        cfg = load_agent_config(args, ap)
    else:
        missing = [flag for flag, v in (("--fcu", args.fcu), ("--swarm", args.swarm), ("--uav", args.uav),
                                        ("--origin", args.origin)) if v is None]
        if missing:
            ap.error(f"{missing[0]} is required" + (f" (also {', '.join(missing[1:])})" if missing[1:] else "")
                     + "; or --config FILE")
        if not 0 <= args.sysid <= 250:
            ap.error("--sysid must be in 1..250 (0: from the UAV id)")
        for spec in args.mavlink_endpoint:
            from uav_stack.mavlink_router import parse_endpoint

            try:
                parse_endpoint(spec)
            except ValueError as exc:
                ap.error(f"--mavlink-endpoint: {exc}")
        try:
            cfg = convert(agent_settings(args, ap), AgentConfig)
        except ConfigError as exc:
            ap.error(flag_error(exc))
    cfg = with_behaviour(cfg, args, ap)
    if cfg.network.discovery is not None:
        try:
            cfg.network.discovery.read_key()  # a key file that cannot be read: say so now, not from the node
        except ConfigError as exc:
            ap.error(f"{'--discovery-key-file' if not args.config else 'network.discovery.key_file'}: {exc.msg}")
    check_security(cfg, args.insecure, ap)
    check_signing_key(cfg, ap)
    problem = fcu_url_problem(cfg.fcu)
    if problem:
        ap.error(f"--fcu {cfg.fcu}: {problem}")
    check_network(cfg, ap, from_file=bool(args.config))
    if cfg.record_dir:
        try:
            Path(cfg.record_dir).mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            ap.error(f"--record-dir {cfg.record_dir}: cannot make it: {exc.strerror or exc}")
    return cfg, args


def agent_main(argv: list[str] | None = None) -> int:
    """``mrswarm agent``: the agent alone, for a real UAV's companion computer (or SITL)."""
    cfg, args = parse_agent(argv)
    lean_zenoh_runtime()
    stop = StopFlag().install()
    setup_logging(args.log_level)
    return run_agent(cfg, stop, args.duration, tap_zenoh_log=True)


def flag_error(exc: ConfigError) -> str:
    """A configuration error from the flags, naming the flag rather than the field (``--origin: lat: ...``)."""
    path = exc.path
    for field_path in sorted(FLAG_OF, key=len, reverse=True):
        if path == field_path or path.startswith(field_path + "."):
            rest = path[len(field_path) + 1:]
            return f"{FLAG_OF[field_path]}: {rest + ': ' if rest else ''}{exc.msg}"
    return str(exc)


def load_agent_config(args: argparse.Namespace, ap: argparse.ArgumentParser) -> AgentConfig:
    """``--config FILE``, with the flags that may go beside it (:data:`WITH_CONFIG`) replacing its fields."""
    from msgspec.structs import replace

    from swarmnet.security.credentials import Credentials

    try:
        cfg = AgentConfig.load(args.config)
    except ConfigError as exc:
        ap.error(f"--config {args.config}: {exc}")
    except OSError as exc:
        ap.error(f"--config {args.config}: cannot read it: {exc.strerror or exc}")
    changes: dict[str, Any] = {}
    if args.fcu is not None:
        changes["fcu"] = args.fcu
    if args.record_dir is not None:
        changes["record_dir"] = args.record_dir
    net = cfg.network
    if args.keys is not None:
        net = replace(net, security=Credentials(keys=args.keys, identity=args.identity or ""))
    elif args.identity is not None:
        if net.security is None:
            ap.error("--identity needs credentials: --keys DIR (the --config file has none)")
        net = replace(net, security=replace(net.security, identity=args.identity))
    return replace(cfg, network=net, **changes)


def check_network(cfg: AgentConfig, ap: argparse.ArgumentParser, from_file: bool = False) -> None:
    """A way to the swarm that can be used: a router (``--connect``) or a discovery server (``--discovery``)."""
    net = cfg.network
    if net.connectivity != "discovery" and not net.endpoints:
        ap.error("no way to the swarm: give --connect ENDPOINT (its edge or rendezvous router, e.g. tls/<edge-server>:7447) "
                 "or --discovery HOST:PORT with --discovery-key-file" if not from_file else
                 f"network.endpoints: none in the --config file, and its connectivity is {net.connectivity!r}")
    for flag, endpoints in (("--connect", net.endpoints), ("--listen", net.listen)):
        for e in endpoints:
            if not ZENOH_ENDPOINT.match(e):
                ap.error(f"{flag if not from_file else 'network.' + flag[2:]} {e}: not a Zenoh endpoint; "
                         "expected PROTOCOL/HOST:PORT, e.g. tls/192.0.2.1:7447")
    try:
        make_connectivity(net, NodeName.uav(cfg.uav, cfg.swarm))
    except ValueError as exc:
        ap.error(f"{'--connect/--listen' if not from_file else 'network'}: {exc}")


def check_security(cfg: AgentConfig, insecure: bool, ap: argparse.ArgumentParser) -> None:
    """Credentials that work now, or an explicit ``--insecure``: say what is wrong before flying."""
    sec = cfg.network.security
    if sec is None:
        if not insecure:
            ap.error("no credentials: give --keys DIR (this UAV's bundle, `mrswarm keys bundle`; docs/security.md), "
                     "or --insecure for plain TCP without access control")
        return
    try:
        creds = sec.for_node(NodeName.uav(cfg.uav, cfg.swarm))
        creds.files()
        creds.roster()
    except ConfigError as exc:
        ap.error(f"--keys: {exc.msg}" if exc.path == "keys" else f"network.security.{exc}")
def agent_settings(args: argparse.Namespace, ap: argparse.ArgumentParser) -> dict[str, Any]:
    """The AgentConfig the flags of ``mrswarm agent`` describe, as a mapping to validate."""
    try:
        lat, lon, alt = (float(v) for v in args.origin.split(","))
    except ValueError:
        ap.error(f"--origin {args.origin}: expected LAT,LON,ALT (degrees, degrees, m AMSL), e.g. -35.36,149.16,584")
    for what, v, lo, hi in (("latitude", lat, -90.0, 90.0), ("longitude", lon, -180.0, 180.0), ("altitude", alt, -500.0, 9000.0)):
        if not lo <= v <= hi:  # also NaN
            ap.error(f"--origin {args.origin}: {what} {v:g} is outside {lo:g}..{hi:g}")
    net: dict[str, Any] = {"endpoints": args.connect, "mode": args.mode, "pose_feed": args.pose_feed,
                           "listen": args.listen or ["tcp/127.0.0.1:0"]}  # a UAV on a network names its address
    if args.keys:
        net["security"] = {"keys": args.keys, "identity": args.identity or ""}
    if args.discovery:
        if not args.discovery_key_file:
            ap.error("--discovery needs --discovery-key-file")
        net.update(connectivity="discovery", discovery={"server": args.discovery, "key_file": args.discovery_key_file,
                                                         "advertise": args.advertise})
    gcs: dict[str, Any] = {"mavlink_endpoints": args.mavlink_endpoint, "sysid": args.sysid, "bind": args.mavlink_bind,
                           "allow_unsigned": args.mavlink_allow_unsigned}
    if args.mavlink_key_file:
        gcs["signing"] = {"key_file": args.mavlink_key_file}
    out = {"swarm": args.swarm, "uav": args.uav, "origin": {"lat": lat, "lon": lon, "alt": alt}, "fcu": args.fcu,
           "fcu_bind": args.fcu_bind, "realm": args.realm, "autostart": args.autostart, "record_dir": args.record_dir,
           "network": net, "gcs": gcs}
    if args.zones:
        out["avoidance"] = {"zones": read_zones(args.zones, ap)}
    return out


def read_zones(path: str, ap: argparse.ArgumentParser) -> Any:
    """The zones of ``--zones``: a scenario's ``world.zones`` or a bare list, in YAML or JSON."""
    import yaml  # once, at the start of the agent; YAML is a superset of JSON

    try:
        data = yaml.safe_load(Path(path).read_text())
    except (OSError, yaml.YAMLError) as exc:
        ap.error(f"--zones {path}: {exc}")
    if isinstance(data, dict):
        data = (data.get("world") or {}).get("zones")
    if not isinstance(data, list):
        ap.error(f"--zones {path}: expected a list of zones, or a scenario with world.zones")
    return data
