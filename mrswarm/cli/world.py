"""``mrswarm world``: run a scenario's world service by hand, at the edge of a real network (docs/world.md).

``mrswarm run`` starts the world service itself. For physical UAVs (or any swarm not started by
``mrswarm run``) run it on the edge server with the scenario and the edge router's endpoint::

    mrswarm world scenarios/wildfire.yaml --connect tls/<edge>:7447 --keys alpha-keys/ [--record results/fire1]

It serves the scenario's swarm and its ``other_swarms``, joining each as a Zenoh client of the
router, as the swarm's ``edge`` identity from its key directory (``--keys DIR`` for the
scenario's swarm, ``--keys SWARM=DIR`` for another; ``--insecure``: plain TCP, no access control).
``--config world.json`` runs a configuration the runner wrote instead.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from groundfloor.process import die_with_parent, setup_logging
from groundfloor.schema import ConfigError
from mrswarm.run.world_setup import observer_network
from mrswarm.scenario import ScenarioError, load_scenario
from uav_stack.config import NetworkConfig
from uav_stack.runtime import StopFlag
from world.config import ServedSwarm, WorldServiceConfig
from world.service import serve


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="mrswarm world", description=__doc__.splitlines()[0])
    ap.add_argument("scenario", nargs="?", help="scenario YAML with a world section")
    ap.add_argument("--config", default=None, help="a world service configuration (JSON) instead of a scenario")
    ap.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                    help="the edge router, e.g. tcp/10.0.0.1:7447 (repeatable)")
    ap.add_argument("--keys", action="append", default=[], metavar="[SWARM=]DIR",
                    help="a swarm's key directory (or the edge's bundle of it): DIR for the scenario's swarm, SWARM=DIR "
                         "for another (docs/security.md)")
    ap.add_argument("--insecure", action="store_true", help="plain TCP without access control")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a scenario field")
    ap.add_argument("--record", default=None, metavar="DIR", help="write the world's records into this folder")
    ap.add_argument("--start", choices=["mission", "now"], default="mission",
                    help="experiment time 0: when a UAV begins its mission (default), or at once")
    ap.add_argument("--duration", type=float, default=None, help="stop after this many seconds")
    ap.add_argument("--log-level", default="INFO")
    args = ap.parse_args(argv)
    setup_logging(args.log_level)
    if args.config:
        try:
            cfg = WorldServiceConfig.load(args.config)
        except (ConfigError, OSError) as exc:
            ap.error(f"{args.config}: {exc}")
    else:
        if not args.scenario or not args.connect:
            ap.error("give a scenario and --connect (the edge router), or --config")
        try:
            scn = load_scenario(args.scenario, args.set)
        except ScenarioError as exc:
            ap.error(str(exc))
        if scn.world is None:
            ap.error(f"{args.scenario}: no world section")
        names = [scn.swarm] + [o.swarm for o in scn.other_swarms]
        keys: dict[str, Path | None] = {}
        for k in args.keys:
            swarm, sep, d = k.rpartition("=")
            keys[swarm if sep else scn.swarm] = Path(d)
        missing = [s for s in names if s not in keys]
        if missing and not args.insecure:
            ap.error(f"no --keys for swarm {', '.join(missing)}: give its key directory, or --insecure")
        net = NetworkConfig(connectivity="rendezvous", endpoints=tuple(args.connect), mode="client")
        swarms = tuple(ServedSwarm(name=s, origin=scn.origin.point(), network=observer_network(net, keys.get(s)))
                       for s in names)
        if args.record:
            Path(args.record).mkdir(parents=True, exist_ok=True)
        cfg = WorldServiceConfig(world=scn.world, swarms=swarms, record_dir=args.record, seed=scn.seed, start=args.start,
                                 duration=args.duration)
    die_with_parent()
    return serve(cfg, StopFlag().install())
