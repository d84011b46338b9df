"""The wildfire mission in closed loop without processes: the world's fire, tanks and virtual sensors
(world/) around the UAVs' firefighting behaviour and collision avoidance (uav_stack/), on the
point-mass swarm of tests/sim_pointmass.py.

Each UAV gets the behaviour, zones and avoidance its agent builds from the scenario (the
scenario's own configuration, through :meth:`Scenario.virtual_uav_configs`): the wildfire
behaviour of the SDK in its guarded adapter, reading this payload; the world computes every
reading from the UAVs' positions at its rate and releases it after its latency, as the world
service does; what a UAV's camera sees (the adapter's outbox, with no agent to send it) is
shared with the others a control tick later.
Fast enough for a behaviour test: a 120 s mission of eight UAVs in seconds.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgspec
import numpy as np

from mrswarm.scenario import Scenario, load_scenario
from swarmnet.messages import Pose, Realm
from tests.sim_pointmass import PointMassSim, SimAgent, SimConfig
from uav_stack.agent import make_mission
from uav_stack.behaviours.avoidance import CollisionAvoidance
from uav_stack.behaviours.zones import zone_field
from uav_stack.config import NetworkConfig
from uav_stack.sdk.adapter import BehaviourMission
from uav_stack.sensors import Payload, VirtualSensor
from world.model import World
from world.sensing import SensorServer, Track

ROOT = Path(__file__).resolve().parents[1]
T0 = 1_000.0  # wall time of the mission start in the simulation


class _Spray:
    """A virtual actuator applied by the world where the UAV is."""

    def __init__(self, name: str, sim: WildfireSim, k: int):
        self.name, self.sim, self.k = name, sim, k

    def actuate(self, amount: float) -> None:
        x, y = self.sim.sim.pos[self.k]
        self.sim.world.actuate(self.sim.key(self.k), self.name, amount, float(x), float(y), self.sim.now)


@dataclass
class WildfireResult:
    min_separation: float  # m, over every pair and physics step
    min_pair: tuple[int, int] | None
    time_below_safety: float  # s, summed over the control ticks with any pair below the safety distance
    cells_extinguished: int
    burning_at_end: int
    entered_zone: bool


class WildfireSim:
    def __init__(self, scenario: Scenario, seed: int = 0, delay: tuple[float, float] = (0.005, 0.03)):
        self.scn = scenario
        assert scenario.world is not None
        self.world = World(scenario.world)
        self.server = SensorServer(self.world, scenario.world.sensors, seed=seed)
        cfgs = [c.agent for c in scenario.virtual_uav_configs(NetworkConfig(), None)]
        self.ids = [c.uav for c in cfgs]
        self.alt = scenario.flight.altitude
        agents = []
        self.payloads: list[dict[str, VirtualSensor]] = []
        for k, c in enumerate(cfgs):
            c = msgspec.structs.replace(c, seed=seed)  # the search draws of UAV u: random.Random(seed * 1_000_003 + u)
            sensors = {s.name: VirtualSensor(s) for s in c.sensors}
            payload = Payload(dict(sensors), {a.name: _Spray(a.name, self, k) for a in c.actuators})
            self.payloads.append(sensors)
            a = c.avoidance
            zones = zone_field(a.zones, a.zone_margin)
            mission = make_mission(c, payload, zones)
            assert isinstance(mission, BehaviourMission)
            avoid = CollisionAvoidance(a.safety_distance, max_speed=c.speed * 1.2, time_horizon=a.time_horizon,
                                       stale_after=a.stale_after, zones=zones)
            start = next(u.start for u in scenario.uav_list() if u.id == c.uav)
            agents.append(SimAgent(c.uav, (float(start[0]), float(start[1])), mission, avoid))  # type: ignore[arg-type]
        self.zones = zone_field(cfgs[0].avoidance.zones, 0.0)
        self.sim = PointMassSim(agents, SimConfig(loss=0.0, delay=delay, seed=seed), keep_trace=True)
        self.sim.on_tick.append(self._world_tick)
        self.world.start(T0)
        self._mail: list[tuple[int, str, Any]] = []
        self.below_ticks = 0

    @property
    def now(self) -> float:
        return T0 + self.sim.t

    def key(self, k: int) -> tuple[str, int]:
        return (self.scn.swarm, self.ids[k])

    def _world_tick(self, sim: PointMassSim) -> None:
        now = self.now
        tracks = {self.key(k): Track(self.scn.swarm, Pose(self.ids[k], Realm.VIRTUAL, 0, sim.t, now, float(p[0]), float(p[1]),
                                                          self.alt, float(v[0]), float(v[1]), 0.0, 0.0))
                  for k, (p, v) in enumerate(zip(sim.pos, sim.vel, strict=True))}
        self.world.advance(now)
        self.world.refill({key: (t.pose.x, t.pose.y) for key, t in tracks.items()}, sim.cfg.control_period)
        self.server.tick(now, tracks)
        for _swarm, r in self.server.release(now):
            sensor = self.payloads[self.ids.index(r.uav)].get(r.sensor)
            if sensor is not None:
                sensor.feed(r, now)
        for src, topic, body in self._mail:  # what the cameras saw a tick ago, to everyone else
            for a in sim.agents:
                if a.uav != src and isinstance(a.mission, BehaviourMission):
                    a.mission.receive(src, topic, body, sim.t)
        self._mail = [(a.uav, topic, body) for a in sim.agents if isinstance(a.mission, BehaviourMission)
                      for topic, body in a.mission.outbox()]
        d = np.linalg.norm(sim.pos[:, None, :] - sim.pos[None, :, :], axis=2)
        np.fill_diagonal(d, np.inf)
        if d.min() < self.scn.flight.safety_distance:
            self.below_ticks += 1

    def run(self, duration: float | None = None) -> WildfireResult:
        res = self.sim.run(duration if duration is not None else self.scn.duration)
        entered = self.zones is not None and any(self.zones.blocked((float(p[k, 0]), float(p[k, 1])), self.alt, 0.0)
                                                 for p in self.sim.trace for k in range(len(self.ids)))
        fire = self.world.fire
        assert fire is not None
        counts = fire.counts()
        return WildfireResult(res.min_separation, res.min_pair, self.below_ticks * self.sim.cfg.control_period,
                              counts.get("extinguished", 0), counts.get("burning", 0), entered)


def wildfire(seed: int = 0, *sets: str) -> WildfireResult:
    return WildfireSim(load_scenario(ROOT / "scenarios" / "wildfire.yaml", list(sets)), seed).run()


if __name__ == "__main__":
    import sys

    for s in range(int(sys.argv[1]) if len(sys.argv) > 1 else 3):
        r = wildfire(s)
        print(f"seed {s}: min {r.min_separation:.2f} m {r.min_pair}, {r.time_below_safety:.1f} s below, "
              f"{r.cells_extinguished} out, {r.burning_at_end} burning, zone entered {r.entered_zone}", flush=True)
