"""The world service: one process at the edge per experiment, serving every swarm of it.

Run by the runtimes beside the discovery server and the edge router (``python -m world
--config world.json``), or by hand for physical UAVs (``mrswarm world SCENARIO --connect
tcp/<edge>:7447``). It joins each swarm as a Zenoh client of the edge router, with a
:class:`~swarmnet.node.SwarmNode` of role ``edge`` (so it inherits the swarm's transport
security), and on a fixed tick (``world.tick_hz``):

1. takes in each swarm's poses (the tracking of Reina et al., here the poses the UAVs share
   anyway), agent states (the first ``mission`` state starts experiment time), actuator
   requests (applied where the world tracks the UAV) and the source estimates the UAVs
   broadcast (recorded);
2. advances the models (fire) to the experiment time and refills tanks at the hub;
3. computes the readings due and publishes those whose latency has passed, each to its UAV;
4. publishes the airspace feed into each swarm (world/airspace.py);
5. records (world/record.py).
"""

from __future__ import annotations

import argparse
import logging
import math
import sys
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

from groundfloor.process import die_with_parent, setup_logging
from groundfloor.schema import ConfigError
from swarmnet.lockstep import IDLE_S as LOCKSTEP_IDLE_S
from swarmnet.lockstep import WORLD, LockstepFollower
from swarmnet.node import NodeIdentity, SwarmNode
from swarmnet.security.identity import NodeName
from swarmnet.sensing import WorldSensing
from uav_stack.behaviours.plume import ESTIMATE_TOPIC
from uav_stack.phases import AgentPhase
from uav_stack.runtime import SimTime, StopFlag, make_connectivity
from uav_stack.sdk.sensing import estimate_in
from world.airspace import TrafficFeed
from world.config import WorldServiceConfig
from world.model import UavKey, World
from world.record import WorldRecorder
from world.sensing import Track

log = logging.getLogger(__name__)

WORLD_NODE_ID = 1  # the world's node id among the role "edge" nodes of a swarm


class WorldService:
    """The world of one experiment on the swarms' network (module docstring). Not thread-safe."""

    def __init__(self, cfg: WorldServiceConfig):
        from world.sensing import SensorServer

        self.cfg = cfg
        # lock-step: every clock of the world reads the simulated time the leader steps (swarmnet/lockstep.py)
        self.sim = SimTime(cfg.lockstep_epoch) if cfg.lockstep_epoch is not None else None
        self.clock: Callable[[], float] = time.time if self.sim is None else self.sim
        w = cfg.world
        self.world = World(w)
        self.sensors = SensorServer(self.world, w.sensors, cfg.seed)
        self.feed = TrafficFeed({s.name: s.origin for s in cfg.swarms}) if w.airspace.feed and len(cfg.swarms) > 1 else None
        self.nodes: dict[str, SwarmNode] = {}
        self.links: dict[str, WorldSensing] = {}
        self.recorder = WorldRecorder(Path(cfg.record_dir), self.world) if cfg.record_dir else None
        self.counts: Counter[str] = Counter()
        self.tracks: dict[UavKey, Track] = {}
        self._next_traffic = 0.0
        self._last_step = math.nan
        self._cpu0 = time.process_time()
        self._wall0 = self.clock()

    def open(self) -> WorldService:
        try:
            for s in self.cfg.swarms:
                conn = make_connectivity(s.network, NodeName("edge", 0, s.name))  # the swarm's edge identity if secured
                # (lock-step: every inlet filled on Zenoh's receive thread, in order with the clock's steps)
                node = SwarmNode(NodeIdentity(s.name, WORLD_NODE_ID, role="edge"), conn, netem_control=False,
                                 clock=self.clock, arrival_stamps=self.sim is None).open()
                self.nodes[s.name] = node
                self.links[s.name] = WorldSensing(node)
        except BaseException:
            self.close()
            raise
        if self.cfg.start == "now":
            self.world.start(self.clock())
        return self

    def close(self) -> None:
        if self.recorder is not None:
            self.recorder.close(self.stats(self.clock()))
            self.recorder = None
        for node in self.nodes.values():
            node.close()
        self.nodes.clear()
        self.links.clear()

    def __enter__(self) -> WorldService:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- one tick -----------------------------------------------------------------------------------
    def step(self, now: float) -> None:
        dt = now - self._last_step if self._last_step == self._last_step else 0.0
        self._last_step = now
        for swarm, node in self.nodes.items():
            self._take_in(swarm, node, now)
        self.world.advance(now)
        if dt > 0.0:
            self.world.refill({k: (t.pose.x, t.pose.y) for k, t in self.tracks.items() if t.fresh(now)}, dt)
        self.sensors.tick(now, self.tracks)
        for swarm, r in self.sensors.release(now):
            link = self.links.get(swarm)
            if link is not None:
                link.publish(r)
        if self.feed is not None and now >= self._next_traffic:
            self._next_traffic = max(self._next_traffic + 1.0 / self.cfg.world.airspace.rate_hz, now)
            for swarm, msg in self.feed.messages(now, self.tracks).items():
                self.links[swarm].publish_traffic(msg)
        if self.recorder is not None:
            self.recorder.sample(now, self.stats(now))

    def _take_in(self, swarm: str, node: SwarmNode, now: float) -> None:
        inbox = node.poll(now)
        for n in node.neighbours:
            self.tracks[(swarm, n.uav)] = Track(swarm, n.pose)
        link = self.links[swarm]
        for st in link.states():
            if st.phase == AgentPhase.MISSION and not self.world.started and self.cfg.start == "mission":
                self.world.start(st.t_wall)
                log.info("experiment time 0: UAV %d of %s began its mission", st.uav, swarm)
        for a in link.actuations():
            tr = self.tracks.get((swarm, a.uav))
            if tr is None or not tr.fresh(now):
                self.counts["actuation_untracked"] += 1
                continue
            x, y, _z = tr.at(now)
            litres, out = self.world.actuate((swarm, a.uav), a.actuator, a.amount, x, y, now)
            self.counts["actuations"] += 1
            self.counts["extinguished"] += out
            if self.recorder is not None:
                self.recorder.actuation(now, swarm, a.uav, a.actuator, x, y, a.amount, litres, out)
        for m in inbox.messages:
            if m.topic == ESTIMATE_TOPIC:  # the plume behaviour's message (uav_stack/sdk/sensing.py), in its envelope
                e = estimate_in(m.body)
                if e is None:
                    self.counts["estimates_rejected"] += 1
                elif self.recorder is not None:
                    self.recorder.estimate(m.t_wall, swarm, m.src, e.x, e.y)
                    self.counts["estimates"] += 1

    def stats(self, now: float) -> dict[str, Any]:
        cpu = time.process_time() - self._cpu0
        wall = now - self._wall0
        return {
            "t0": self.world.t0,
            "t_s": self.world.time(now),
            "written_at": now,
            "cpu_s": round(cpu, 3),
            "wall_s": round(wall, 3),
            "cpu_percent": round(100.0 * cpu / wall, 2) if wall > 0 else None,
            "uavs_tracked": sum(1 for t in self.tracks.values() if t.fresh(now)),
            "readings": dict(self.sensors.computed),
            "counts": dict(self.counts),
            "traffic_reports": self.feed.reports if self.feed is not None else 0,
            "tanks": {f"{k[0][0]}/{k[0][1]}/{k[1]}": {"level_l": round(t.level, 3), "released_l": round(t.released, 3),
                                                       "refused": t.refused} for k, t in self.world.tanks.items()},
            "net": {s: n.stats.to_dict() for s, n in self.nodes.items()},
            "fire": ({**self.world.fire.counts(), "burnt_area_m2": self.world.fire.burnt_area_m2,
                      "out_at_s": self.world.fire.out_at, "sprayed_l": round(self.world.fire.sprayed_l, 3)}
                     if self.world.fire is not None else None),
        }

    def run_lockstep(self, stop: StopFlag, idle_timeout: float = LOCKSTEP_IDLE_S) -> None:
        """Lock-step time: a step of the world each time the run's leader steps it (once a tick, after
        the pools), at the tick's instant, until stopped, after ``duration`` s of simulated time, or when
        no step came for ``idle_timeout`` s of wall time (the leader is gone)."""
        sim = self.sim
        assert sim is not None
        first = next(iter(self.nodes.values()))
        assert first.session is not None
        follower = LockstepFollower(first.session, first.keys, WORLD)
        end = sim.now + self.cfg.duration if self.cfg.duration is not None else math.inf
        try:
            for step in follower.follow(lambda: stop.stopped or sim.now >= end, idle_timeout):
                sim.now = step.t
                self.step(step.t)
                follower.done(step)
        finally:
            follower.close()

    def run(self, stop: StopFlag) -> None:
        """Tick at ``world.tick_hz`` until stopped (or ``duration`` seconds); in lock-step time when the
        leader steps it."""
        if self.sim is not None:
            self.run_lockstep(stop)
            return
        period = 1.0 / self.cfg.world.tick_hz
        end = time.monotonic() + self.cfg.duration if self.cfg.duration is not None else math.inf
        next_tick = time.monotonic()
        while not stop.stopped and time.monotonic() < end:
            now_m = time.monotonic()
            if next_tick > now_m:
                time.sleep(min(next_tick, end) - now_m)
                continue
            next_tick = max(next_tick + period, now_m)
            self.step(time.time())


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m world", description="the world service of an experiment (docs/world.md)")
    ap.add_argument("--config", required=True, help="JSON written by the runner (WorldServiceConfig)")
    ap.add_argument("--log-level", default="INFO")
    ap.add_argument("--die-with-parent", action="store_true", help="exit when the launching process dies (runtimes)")
    args = ap.parse_args(argv)
    if args.die_with_parent:
        die_with_parent()
    stop = StopFlag().install()
    setup_logging(args.log_level)
    try:
        cfg = WorldServiceConfig.load(args.config)
    except (ConfigError, OSError) as exc:
        ap.error(f"{args.config}: {exc}")
    return serve(cfg, stop)


def serve(cfg: WorldServiceConfig, stop: StopFlag) -> int:
    with WorldService(cfg) as svc:
        print(f"world service: swarms {', '.join(s.name for s in cfg.swarms)}; "
              f"sensors {', '.join(s.name for s in cfg.world.sensors) or 'none'}", flush=True)
        svc.run(stop)
    return 0


if __name__ == "__main__":
    sys.exit(main())
