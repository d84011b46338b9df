"""A pool of virtual UAVs in one process: ``python -m uav_stack.pool --config pool1.json``.

Each pooled UAV is still its own UAV: its own agent (the same code as an isolated virtual UAV's
or a real UAV's companion), its own id, its own credentials and swarm node (so its own keys in
the key space, under access control), its own vehicle of the virtual FCU with its own MAVLink
link and, when asked for, its own ground-station endpoint. That link carries the same MAVLink
datagrams as a lone virtual UAV's, through an in-process channel (``inproc:<name>``,
:mod:`uav_stack.inproc`) rather than a UDP socket pair: the agent's FCU link is the same code.
What the pool shares is the process: one interpreter, one virtual FCU stepping every vehicle
together (struct of arrays), one loop, and Zenoh's runtime threads. A process per UAV costs an
interpreter and its imports each (about 60 MB and a share of a core's wake-ups); a pool pays them
once (docs/scale.md).

The loop runs every UAV's tick at the same instants, in two halves as aligned ticks do
(:func:`uav_stack.runtime.run_loop`): the FCU's step and every UAV's sense (FCU in, own pose
out), then, once the poses of the instant have had :data:`ACT_AFTER` of a period to arrive,
every UAV's act (control, setpoints, reports). A UAV of the pool whose agent raises is logged
and counted (an ``agent_error`` incident of the run); the others fly on. In lock-step time
(:meth:`Pool.run_lockstep`) the same two halves run when the run's leader steps the pool, at the
step's simulated time, which every clock of the pool reads (swarmnet/lockstep.py).
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import random
import selectors
import sys
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import msgspec
from msgspec import Meta

from groundfloor.schema import Config, ConfigError, decode_json
from swarmnet.keyspace import SwarmKeys
from swarmnet.lockstep import IDLE_S as LOCKSTEP_IDLE_S
from swarmnet.lockstep import LockstepFollower
from swarmnet.neighbours import neighbour_counters
from uav_stack.config import MAX_POOL, VirtualUavConfig
from uav_stack.fcu_link import LinkOpenError
from uav_stack.recorder import RecordHealth, SwappedJsonFile, pool_neighbours_file_name
from uav_stack.runtime import (
    FCU_LEAD_S,
    LoopStats,
    SimTime,
    StopFlag,
    VirtualUav,
    check_signing_key,
    make_virtual_fcu,
    next_grid_instant,
    open_shared_session,
    open_virtual_uav,
    shares_session,
    tick_hz_for,
    virtual_process_start,
)

if TYPE_CHECKING:
    from swarmnet.shared_session import SharedSession
    from uav_stack.fcu import VirtualFcu
    from uav_stack.sim_faults import SimFaults

log = logging.getLogger(__name__)

PUT_TOGETHER = 16  # UAVs whose puts of a half tick leave back to back: a pose waits for at most their work
ACT_AFTER = 0.3  # of a period after the instant: when the pool acts (its UAVs' poses of the instant are in by then)
# lock-step time: s of simulated time after the instant at which the pool acts. In real time a pool acts as
# soon as the instant's poses are in, about 10 ms after it on 2 cores (5 ms transport, 4 ms to use), at
# ACT_AFTER at the latest; in lock-step every pose is in at once, so the act comes when it would on the wire
LOCKSTEP_ACT_S = 0.01


class PoolConfig(Config, frozen=True):
    """The virtual UAVs of one pool process (what the runner writes, ``pool<N>.json``)."""

    uavs: Annotated[tuple[VirtualUavConfig, ...], Meta(min_length=1, max_length=MAX_POOL)]
    # the pool's number in its run: its session speaks as pool-<number> (docs/security.md)
    number: Annotated[int, Meta(ge=1, le=65535)] = 1
    # stop the process after this long (None: until signalled)
    duration: Annotated[float, Meta(gt=0.0, description="s")] | None = None
    # lock-step time (swarmnet/lockstep.py): the simulated time of the first instant, s since the Unix
    # epoch; the pool runs each tick when the run's leader steps it. None: real time
    lockstep_epoch: Annotated[float, Meta(gt=0.0, description="s")] | None = None

    def __post_init__(self) -> None:
        first = self.uavs[0]
        ids = [u.agent.uav for u in self.uavs]
        if len(set(ids)) != len(ids):
            raise ConfigError("uavs", f"a UAV id twice in one pool: {sorted(ids)}")
        for i, u in enumerate(self.uavs):
            for name in ("target_rtf", "physics_hz", "flavour"):
                if getattr(u, name) != getattr(first, name):
                    raise ConfigError(f"uavs[{i}].{name}", f"{getattr(u, name)!r}, but {getattr(first, name)!r} for the "
                                      "pool's first UAV: one virtual FCU steps a pool (one flavour, rate and RTF)")

    def to_json(self) -> str:
        return msgspec.json.encode(self).decode()

    @classmethod
    def load(cls, path: str) -> PoolConfig:
        with open(path, "rb") as f:
            return decode_json(f.read(), cls)


class PooledFcu:
    """The pool's virtual FCU as its loop drives it, with each vehicle's injected faults: a vehicle
    whose link is cut loses what its agent sends; the others' datagrams are handled."""

    def __init__(self, fcu: VirtualFcu, faults: list[SimFaults]):
        self.fcu = fcu
        self.faults = faults

    def poll_io(self) -> None:
        cut = [f for f in self.faults if f.cut]
        if not cut:
            self.fcu.poll_io()
            return
        for f in cut:  # datagrams from the agent are lost on the cut link
            f.dropped_datagrams += len(f.vehicle.link.recv())
        self.fcu.poll_io(vehicles=[f.vehicle for f in self.faults if not f.cut])

    def service(self, now: float, fcu_now: float | None = None) -> None:
        """The FCU's due steps (by ``fcu_now`` on its clock: default its own), faults updated to ``now``."""
        for f in self.faults:
            f.update(now)
        self.fcu.service(fcu_now)


class Pool:
    """The UAVs of one pool and the loop that drives them."""

    def __init__(self, uavs: list[VirtualUav], fcu: VirtualFcu,
                 neighbour_files: list[tuple[SharedSession, SwappedJsonFile]] | None = None,
                 clock: Callable[[], float] = time.time):
        self.uavs = uavs
        self.clock = clock  # what the UAVs are told the time is: the wall clock, or lock-step's simulated time
        self.neighbour_files = neighbour_files or []  # each shared session's per-neighbour counters, once a second
        self.records = RecordHealth()
        self.fcu = PooledFcu(fcu, [u.faults for u in uavs])
        self.errors: dict[int, int] = {}  # UAV id -> exceptions its agent raised (logged, counted, never fatal)
        self.first_error: dict[int, dict[str, object]] = {}  # UAV id -> {"t", "what", "error"} of its first
        for u in uavs:  # in each UAV's stats: the summary makes an incident of them (agent_error)
            u.agent.stats_sources["pool"] = partial(self._errors_of, u.agent.uav)
        self._sel = selectors.DefaultSelector()
        for u in uavs:  # a command or an injected fault wakes the loop, for the UAV it is for
            self._sel.register(u.agent.node.waker.fileno(), selectors.EVENT_READ, u)
        self._shares = list({id(s): s for u in uavs if (s := u.agent.node.shared) is not None}.values())

    def run(self, stop: StopFlag, period: float, duration: float | None = None) -> None:
        """Tick every UAV on the wall clock's grid (``period`` s) until stopped or ``duration`` s pass."""
        parent = os.getppid()
        loop = LoopStats(period)  # the pool's loop is each of its UAVs' loop
        for u in self.uavs:
            u.agent.stats_sources["loop"] = loop.as_dict
        t0 = time.monotonic()
        end = math.inf if duration is None else t0 + duration
        next_sense = next_grid_instant(t0, period)
        next_counters = t0 + 1.0
        next_act = math.inf
        while not stop.stopped:
            now_m = time.monotonic()
            if now_m >= end:
                break
            due = min(next_sense, next_act)
            if due > now_m:
                self._wait(min(due, end) - now_m)
                continue
            if next_act <= next_sense:  # the act of the last instant first, even when late
                next_act = math.inf
                self.fcu.poll_io()
                self._each("act")
                self.fcu.poll_io()  # the setpoints just sent: applied now
                continue
            instant = next_sense
            loop.tick(now_m - instant)
            next_sense = next_grid_instant(now_m, period)
            next_act = max(instant, next_sense - period) + ACT_AFTER * period
            self.fcu.poll_io()
            self.fcu.service(time.time())
            self._each("sense")
            self.fcu.poll_io()
            if now_m >= next_counters:
                next_counters = now_m + 1.0
                self.write_neighbours()
            if os.getppid() != parent:  # re-parented: the launcher is gone
                break

    def run_lockstep(self, stop: StopFlag, follower: LockstepFollower, sim: SimTime, period: float,
                     duration: float | None = None, idle_timeout: float = LOCKSTEP_IDLE_S) -> None:
        """Each tick when the leader steps it, at the step's simulated time, as fast as the steps come
        (swarmnet/lockstep.py): the FCU steps to :data:`LOCKSTEP_ACT_S` after the last instant and every
        UAV acts on the poses of that instant (as in real time: its setpoints apply from then on), then
        the FCU steps to the new instant and every UAV senses and its pose goes out. A UAV's command
        or fault is taken in at the start of the step. Ends when stopped, after ``duration`` s of
        simulated time, or when no step came for ``idle_timeout`` s of wall time (the leader is gone)."""
        parent = os.getppid()
        loop = LoopStats(period)
        for u in self.uavs:
            u.agent.stats_sources["loop"] = loop.as_dict
        end = math.inf if duration is None else sim.now + duration
        next_counters = time.monotonic() + 1.0
        answered: float | None = None  # perf_counter of the last answer (the wait for the next step starts there)
        for step in follower.follow(lambda: stop.stopped or sim.now >= end, idle_timeout,
                                   gone=lambda: os.getppid() != parent):
            began, cpu = time.perf_counter(), time.thread_time()
            if step.k > 0:  # the act of the last instant, when it comes in real time: the FCU flies on to it first
                self._instant(step.t - period)
                sim.now = t_act = step.t - period + LOCKSTEP_ACT_S
                self.fcu.service(t_act, t_act)
                self._react_woken()
                self.fcu.poll_io()
                self._each("act")
                self.fcu.poll_io()  # the setpoints just sent: taken in at the act's time (as in real time)
            self._instant(step.t)
            sim.now = step.t
            loop.tick(0.0)
            self.fcu.poll_io()
            self.fcu.service(step.t, step.t)
            self._each("sense")
            self.fcu.poll_io()
            follower.done(step)
            now = time.perf_counter()
            loop.step(now - began, time.thread_time() - cpu, began - answered if answered is not None else None)
            answered = now
            if (wall := time.monotonic()) >= next_counters:  # (files on the wall clock: a faster run does not write more often)
                next_counters = wall + 1.0
                self.write_neighbours()

    def _instant(self, t: float) -> None:
        """Lock-step: the UAVs see the poses of instant ``t`` and before, not those a pool ahead sent since."""
        for share in self._shares:
            share.instant = t

    def _react_woken(self) -> None:
        for key, _ in self._sel.select(0):
            u: VirtualUav = key.data
            u.agent.node.waker.clear()
            self._guarded(u, "react")

    def _wait(self, timeout: float) -> None:
        for key, _ in self._sel.select(timeout):
            u: VirtualUav = key.data
            u.agent.node.waker.clear()  # (as Waker.wait does: else the descriptor stays readable)
            self._guarded(u, "react")

    def _each(self, half: str) -> None:
        uavs = self.uavs
        for i in range(0, len(uavs), PUT_TOGETHER):
            with contextlib.ExitStack() as held:  # their puts back to back (SharedSession.together)
                for share in self._shares:
                    held.enter_context(share.together())
                for u in uavs[i:i + PUT_TOGETHER]:
                    self._guarded(u, half)

    def _guarded(self, u: VirtualUav, what: str) -> None:
        try:
            getattr(u.agent, what)(self.clock())
        except Exception as exc:  # noqa: BLE001 - one UAV's failure never takes its pool-mates down
            n = self.errors[u.agent.uav] = self.errors.get(u.agent.uav, 0) + 1
            if n == 1:
                self.first_error[u.agent.uav] = {"t": self.clock(), "what": what,
                                                 "error": f"{type(exc).__name__}: {exc}"[:300]}
            if n == 1 or n % 100 == 0:
                log.exception("UAV %d: %s failed (%d so far); the pool flies on", u.agent.uav, what, n)

    def _errors_of(self, uav: int) -> dict[str, object]:
        return {"agent_errors": self.errors.get(uav, 0), "first_error": self.first_error.get(uav)}

    def write_neighbours(self) -> None:
        """Each shared session's per-neighbour pose counters, in the file its UAVs' counters files
        name (``neighbours_in``): once for the pool instead of once per UAV."""
        now = self.clock()
        for share, out in self.neighbour_files:
            out.write({"pool": share.name, "written_at": now, "neighbours": neighbour_counters(share.neighbours)},
                      self.records, now)

    def close(self) -> None:
        """The loop's own resources; the UAVs are closed by their opener (:func:`run_pool`)."""
        self._sel.close()
        for _, out in self.neighbour_files:
            out.close()


def run_pool(cfg: PoolConfig, stop: StopFlag, tap_zenoh_log: bool = False) -> int:
    cfgs = list(cfg.uavs)
    period = 1.0 / max(tick_hz_for(c.agent) for c in cfgs)
    # lock-step: every clock of the pool (FCU, nodes, agents) reads the simulated time the leader steps
    sim = SimTime(cfg.lockstep_epoch) if cfg.lockstep_epoch is not None else None
    # the FCU's 10 Hz positions on the ticks' grid, a hair before each instant (as a UAV process's, aligned)
    # every agent is in this process: each vehicle's link an in-process channel, not a socket pair
    if sim is None:
        fcu = make_virtual_fcu(cfgs, time.monotonic() - (time.time() % period) - FCU_LEAD_S, inproc=True)
    else:
        # its heartbeats between the ticks, where a real boot's fall, at a phase the seed draws (one seed, one flight)
        beat = random.Random(f"{cfgs[0].agent.seed}/pool-{cfg.number}").random()
        fcu = make_virtual_fcu(cfgs, sim.now - FCU_LEAD_S, inproc=True, clock=sim, heartbeat_offset_s=beat)
    clock: Callable[[], float] = time.time if sim is None else sim
    uavs: list[VirtualUav] = []
    shares: dict[str, SharedSession] = {}  # swarm -> the pool's one session for its UAVs of that swarm
    try:
        swarms = _by_swarm(cfgs)
        if shares_session(cfgs[0].agent.network):
            for swarm, members in swarms.items():
                shares[swarm] = open_shared_session([c.agent for c in members], cfg.number, stop, clock=clock,
                                                    lockstep=sim is not None)
        for i, c in enumerate(cfgs):
            if stop.stopped:
                return 0
            share = shares.get(c.agent.swarm)
            try:
                uavs.append(open_virtual_uav(c, fcu, i, stop, tap_zenoh_log=tap_zenoh_log and i == 0, shared=share,
                                             clock=clock))
            except LinkOpenError as exc:
                log.error("UAV %d: %s", c.agent.uav, exc)
                return 2
            if share is not None:  # the pool session's own counters (poses, rejections, links) in each UAV's stats
                ids = [m.agent.uav for m in swarms[c.agent.swarm]]
                uavs[-1].agent.stats_sources["pool_session"] = partial(_session_stats, share, ids)
        files = []
        if cfgs[0].agent.record_dir and len(shares) == 1:  # the pool's UAVs share one table: its counters once, in one file
            (share,) = shares.values()  # (a pool holds one swarm: Scenario.pool_layout; else each UAV writes its own)
            name = pool_neighbours_file_name(cfg.number)
            for u in uavs:
                u.agent.neighbours_in = name
            files = [(share, SwappedJsonFile(Path(cfgs[0].agent.record_dir) / name))]
        pool = Pool(uavs, fcu, files, clock)
        log.info("pool of %d virtual UAVs (%s) flying", len(uavs), ", ".join(str(c.agent.uav) for c in cfgs))
        try:
            if not _fly(pool, cfg, stop, period, sim, shares):
                return 2
        finally:
            pool.write_neighbours()  # the last counters, as each UAV writes its own at the end
            pool.close()
    finally:
        for u in uavs:
            try:
                u.close()
            except Exception:  # noqa: BLE001 - close the others too
                log.exception("UAV %d: close failed", u.agent.uav)
        for share in shares.values():  # after its members
            share.close()
        fcu.close()
    return 0


def _fly(pool: Pool, cfg: PoolConfig, stop: StopFlag, period: float, sim: SimTime | None,
         shares: dict[str, SharedSession]) -> bool:
    """The pool's loop on the wall clock, or on the run's lock-step clock (False: it cannot follow one)."""
    if sim is None:
        pool.run(stop, period, cfg.duration)
        return True
    session = next(iter(shares.values())).session if len(shares) == 1 else None
    if session is None:
        log.error("lock-step time needs the pool's UAVs on one shared session (one swarm, client mode)")
        return False
    (share,) = shares.values()
    share.message_hold_s = period  # a swarm message is taken at the receivers' next act (swarmnet/lockstep.py)
    follower = LockstepFollower(session, SwarmKeys(cfg.uavs[0].agent.swarm), cfg.number)
    log.info("lock-step time: waiting for the run's leader")
    try:
        pool.run_lockstep(stop, follower, sim, period, cfg.duration)
    finally:
        follower.close()
    return True


def _by_swarm(cfgs: list[VirtualUavConfig]) -> dict[str, list[VirtualUavConfig]]:
    out: dict[str, list[VirtualUavConfig]] = {}
    for c in cfgs:
        out.setdefault(c.agent.swarm, []).append(c)
    return out


def _session_stats(share: SharedSession, uavs: list[int]) -> dict[str, object]:
    st = share.stats
    return {"name": share.name, "uavs": uavs, "received": dict(st.received), "rejected": dict(st.rejected),
            "refused": dict(st.refused)}


def main(argv: list[str] | None = None) -> int:
    """``python -m uav_stack.pool --config pool1.json``: what the process runtime launches for a pool."""
    cfg, stop, ap = virtual_process_start("python -m uav_stack.pool",
                                          "a pool of virtual UAVs in one process: one virtual FCU, an agent each",
                                          PoolConfig.load, argv)
    for c in cfg.uavs:
        check_signing_key(c.agent, ap)
    return run_pool(cfg, stop, tap_zenoh_log=True)


if __name__ == "__main__":
    sys.exit(main())
