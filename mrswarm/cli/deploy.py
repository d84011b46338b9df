"""``mrswarm deploy``: the commands of ``deploy/cli.py``, and ``swarm up``, which starts from a scenario.

``deploy/`` sits below mrswarm and never reads scenarios: this module turns one into the
typed :class:`deploy.swarm.Fleet` (services and per-UAV configs) and the stack options, and
hands those to ``deploy.swarm``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING

from msgspec.structs import replace

from deploy.dockerutil import DeployError
from deploy.swarm import DATA_PATH, Fleet, StackOptions

if TYPE_CHECKING:
    from mrswarm.scenario import Scenario


STACK_KEYS = Path("keys")  # a secured stack's key directory, beside its stack file (unless the scenario names one)


def swarm_fleet(scn: Scenario, uavs: int, autostart: bool = False) -> Fleet:
    """The first ``uavs`` UAVs of the scenario as swarm-mode replicas (they reach the services by DNS name).

    Secured (the default): the stack takes its credentials from ``network.security.keys``, else
    from ``keys/`` beside the stack file (:func:`stack_keys` fills it)."""
    from deploy.plan import CONTAINERS

    if uavs < 1:
        raise DeployError(f"--uavs must be at least 1, got {uavs}")
    if scn.fleet is not None:
        scn = replace(scn, fleet=replace(scn.fleet, count=uavs))
    elif len(virtual := [u for u in scn.uav_list() if not u.external]) < uavs:
        external = len(scn.uav_list()) - len(virtual)
        raise DeployError(f"scenario {scn.name} lists {len(virtual)} virtual UAVs; cannot deploy {uavs}"
                          + (f" (its {external} with an external flight controller run their own agent: mrswarm agent)"
                             if external else ""))
    sec = scn.network.secured
    keys = (Path(sec.keys).resolve() if sec.keys else STACK_KEYS) if sec.enabled else None
    # the run's plan, placed in containers as the container runtime places it; a fresh discovery key per
    # deployment unless the scenario sets one
    network = scn.network_plan({scn.swarm: keys}).place(CONTAINERS)
    netcfg = network.uav_network(scn.swarm, {s.name: s.name for s in network.services})  # by DNS name
    cfgs = scn.virtual_uav_configs(netcfg, record_dir=f"{DATA_PATH}/{scn.swarm}")[:uavs]
    if autostart:
        cfgs = [replace(c, agent=replace(c.agent, autostart=True)) for c in cfgs]
    return Fleet(network, tuple(cfgs))


def stack_keys(fleet: Fleet, out: Path) -> None:
    """The credentials a secured stack needs: the scenario's key directory must hold them; the
    stack's own (``<out>/keys``, made on first use and kept) gets whatever identity is missing."""
    from mrswarm.run.keys import check_keys, ensure_keys
    from swarmnet.security.identity import NodeName
    from swarmnet.security.pki import KeysError

    if fleet.keys is None:
        return
    names = [NodeName("edge", 0, fleet.swarm), NodeName("ctl", 0, fleet.swarm), NodeName("gcs", 1, fleet.swarm),
             *(NodeName.uav(c.agent.uav, fleet.swarm) for c in fleet.uavs)]
    try:
        if fleet.keys.is_absolute():
            check_keys(fleet.keys, fleet.swarm, names)
        else:
            ensure_keys(out / fleet.keys, fleet.swarm, names)
    except KeysError as exc:
        raise DeployError(f"network.security.keys: {exc}") from None


def _swarm_up(args: argparse.Namespace) -> int:
    from deploy import swarm
    from deploy.dockerutil import client
    from deploy.images import image_tag
    from mrswarm.scenario import ScenarioError, load_scenario

    overrides = list(args.set) + ([f"swarm={args.swarm}"] if args.swarm else [])
    try:
        scn = load_scenario(args.scenario, overrides)
    except ScenarioError as exc:
        raise DeployError(str(exc)) from None
    fleet = swarm_fleet(scn, args.uavs, args.autostart)
    edges = swarm.edge_hosts(client()) if args.edge_per_node and not args.dry_run else ()
    opts = StackOptions(image=args.image or scn.docker.image or image_tag(), container=scn.docker, port=args.port,
                        max_per_node=args.max_per_node, log_level=args.log_level, edges=edges)
    out = Path(args.out or f"build/swarm/{swarm.stack_name(scn.swarm)}")
    if args.dry_run:
        print(swarm.write_stack(fleet, opts, out))
        return 0
    stack_keys(fleet, out)
    if args.init and swarm.init_swarm(client()):
        print("initialised a single-node swarm (this engine is its manager)")
    print(json.dumps(swarm.up(fleet, opts, out, wait=args.wait), indent=2))
    return 0


def main(argv: list[str] | None = None) -> int:
    from deploy import cli

    return cli.main(argv, swarm_up=_swarm_up)
