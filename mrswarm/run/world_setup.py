"""The runner's part of the world (docs/world.md): every swarm's network, its UAVs, the world service, the observers.

A scenario may fly more than one swarm in one airspace (``other_swarms``). Each swarm has its
own discovery key (drawn per run unless the scenario gives one), its own credentials (a
throw-away CA per swarm and run, like the scenario's swarm unless ``network.security`` is off),
its own edge router and its own sessions: its UAVs find only each other, and the runner watches
and commands each swarm through an observer of its own, as that swarm's ``ctl``. The world
service joins every swarm as a client of its edge router, as that swarm's ``edge``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from msgspec.structs import replace

from groundfloor.files import write_atomic
from mrswarm.scenario import Scenario
from swarmnet.connectivity import Connectivity, open_retrying
from swarmnet.lockstep import LOCKSTEP_EPOCH
from swarmnet.messages import Command, Pose
from swarmnet.observer import PendingCommand, SwarmObserver
from swarmnet.security.credentials import Credentials
from swarmnet.security.identity import NodeName
from uav_stack.config import AgentConfig, NetworkConfig, VirtualUavConfig
from uav_stack.runtime import OPEN_TIMEOUT_S, make_connectivity
from world.config import ServedSwarm, WorldServiceConfig


def other_swarm_credentials(scn: Scenario, run_dir: Path, secured: bool) -> dict[str, Path | None]:
    """Every other swarm's key directory for this run: a throw-away CA each (``<run>/keys-<swarm>``)
    with its UAVs, its edge, its ctl and one ground station; None each when the run is not secured."""
    if not secured:
        return {o.swarm: None for o in scn.other_swarms}
    from mrswarm.run.keys import run_identities, throwaway_keys

    return {o.swarm: throwaway_keys(run_dir / f"keys-{o.swarm}", o.swarm, run_identities(o.swarm, [u.id for u in o.uav_list()]),
                                    pools=scn.pool_numbers(o.swarm))
            for o in scn.other_swarms}


def observer_network(net: NetworkConfig, keys: Path | None) -> NetworkConfig:
    """How the runner and the world service join a swarm: as clients of its edge router if there
    is one (rendezvous, or discovery with the router beside it), else as discovery peers; with
    the swarm's key directory as seen from here (the identity is the caller's: ctl, edge)."""
    own = Credentials(keys=str(keys)) if keys is not None else None
    if net.endpoints:
        return NetworkConfig(connectivity="rendezvous", endpoints=net.endpoints, mode="client", lease_s=net.lease_s, security=own)
    return replace(net, security=own)


def uav_configs(scn: Scenario, nets: dict[str, NetworkConfig], record_dir: str | None,
                mavlink_key: Path | None = None) -> list[VirtualUavConfig]:
    """Every virtual UAV process of every swarm; ``mavlink_key``: the MAVLink signing passphrase file when
    it is not in the UAVs' key directories (Scenario.virtual_uav_configs)."""
    key = str(mavlink_key) if mavlink_key is not None else None
    out = scn.virtual_uav_configs(nets[scn.swarm], record_dir, mavlink_key=key)
    for o in scn.other_swarms:
        out += scn.virtual_uav_configs(nets[o.swarm], record_dir, other=o, mavlink_key=key)
    return out


def external_agents(scn: Scenario, nets: dict[str, NetworkConfig], record_dir: str | None,
                    mavlink_key: Path | None = None) -> list[AgentConfig]:
    """The agent of every UAV whose flight controller is external, in every swarm (``uavs[].fcu``);
    ``mavlink_key`` as for :func:`uav_configs`."""
    key = str(mavlink_key) if mavlink_key is not None else None
    out = scn.external_agent_configs(nets[scn.swarm], record_dir, mavlink_key=key)
    for o in scn.other_swarms:
        out += scn.external_agent_configs(nets[o.swarm], record_dir, other=o, mavlink_key=key)
    return out


def world_service_config(scn: Scenario, nets: dict[str, NetworkConfig], keys: dict[str, Path | None],
                         record_dir: Path | None) -> WorldServiceConfig | None:
    """What the world service of this run reads (None: the scenario has no world)."""
    if scn.world is None:
        return None
    origin = scn.origin.point()
    swarms = tuple(ServedSwarm(name=s, origin=origin, network=observer_network(n, keys.get(s))) for s, n in nets.items())
    return WorldServiceConfig(world=scn.world, swarms=swarms, record_dir=str(record_dir) if record_dir else None,
                              seed=scn.seed, lockstep_epoch=LOCKSTEP_EPOCH if scn.time == "lockstep" else None)


def write_world_config(cfg: WorldServiceConfig, run_dir: Path) -> Path:
    path = run_dir / "config" / "world.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, cfg.to_json(), private=True)  # it holds the swarms' discovery keys
    return path


class FleetObserver(SwarmObserver):
    """The runner's view of several swarms: this observer for the first, one more per other swarm.

    Each swarm is watched and commanded through its own session, as its operators would with
    their own credentials; ``uavs`` holds every UAV of every swarm (their ids differ), and a
    command to some UAVs goes to each one through its own swarm.
    """

    def __init__(self, swarms: list[tuple[str, Connectivity, set[int]]], name: str = "runner"):
        first, conn, ids = swarms[0]
        super().__init__(first, conn, name=name)
        self.members = {first: ids}
        self.others: list[SwarmObserver] = []
        for swarm, c, uav_ids in swarms[1:]:
            self.others.append(SwarmObserver(swarm, c, name=name))
            self.members[swarm] = uav_ids
        self._combined: list[tuple[PendingCommand, list[PendingCommand]]] = []

    def open(self) -> FleetObserver:
        super().open()
        for o in self.others:
            o.open()
        return self

    def close(self) -> None:
        for o in self.others:
            o.close()
        super().close()

    def poll(self) -> list[Pose]:
        fresh = super().poll()
        for o in self.others:
            fresh += o.poll()
            self.uavs.update(o.uavs)
        for combined, parts in self._combined:
            for p in parts:
                combined.acks.update(p.acks)
        self._combined = [(c, parts) for c, parts in self._combined if not c.complete]
        return fresh

    def alive_uavs(self) -> set[int]:
        out = super().alive_uavs()
        for o in self.others:
            out |= o.alive_uavs()
        return out

    def command(self, verb: str, targets: Iterable[int] | None = None, args: dict[str, Any] | None = None) -> PendingCommand:
        tset = set(targets) if targets is not None else self.alive_uavs()
        first = next(iter(self.members))
        parts = []
        mine = tset & self.members[first]
        if mine:
            parts.append(super().command(verb, mine, args))
        for o in self.others:
            theirs = tset & self.members[o.keys.swarm]
            if theirs:
                parts.append(o.command(verb, theirs, args))
        cmd = parts[0].cmd if parts else Command(self.name, 0, 0, verb, args or {}, self.clock())
        combined = PendingCommand(cmd, tset)
        self._combined.append((combined, parts))
        return combined


def open_observer(scn: Scenario, nets: dict[str, NetworkConfig], keys: dict[str, Path | None],
                  name: str = "runner", clock: Callable[[], float] = time.time) -> SwarmObserver:
    """The runner's observer (as each swarm's ``ctl``): of the scenario's swarm, or of every swarm of the airspace."""

    def conn(s: str) -> Connectivity:
        return make_connectivity(observer_network(nets[s], keys.get(s)), NodeName("ctl", 0, s))

    obs: SwarmObserver
    if not scn.other_swarms:
        obs = SwarmObserver(scn.swarm, conn(scn.swarm), name=name, clock=clock)
    else:
        swarm_ids = {scn.swarm: {u.id for u in scn.uav_list()}} | {o.swarm: {u.id for u in o.uav_list()} for o in
                                                                   scn.other_swarms}
        obs = FleetObserver([(s, conn(s), swarm_ids[s]) for s in nets], name=name)
    # the edge router may still be busy accepting a whole swarm: try again, as long as the UAVs do
    return open_retrying(obs.open, OPEN_TIMEOUT_S, name)
