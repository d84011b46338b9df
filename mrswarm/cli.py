"""The ``mrswarm`` command: one CLI, a subcommand per job.

Heavy imports happen inside each subcommand, so ``mrswarm agent`` on a companion computer
does not load matplotlib.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def _run(args: argparse.Namespace) -> int:
    from rich.console import Console

    from mrswarm.experiment import Experiment
    from mrswarm.scenario import ScenarioError, load_scenario
    from mrswarm.summary_table import print_summary

    console = Console()
    try:
        scn = load_scenario(args.scenario, args.set + ([f"runtime={args.runtime}"] if args.runtime else []))
    except ScenarioError as exc:
        console.print(f"[red]error:[/] {exc}", highlight=False)
        return 2
    try:
        exp = Experiment(scn, Path(args.out), console=console, live=not args.no_live, log_level=args.log_level,
                         record=not args.no_record)
    except RuntimeError as exc:  # a runtime that cannot start (no docker engine, no image, ...)
        console.print(f"[red]error:[/] {exc}", highlight=False)
        return 2
    summary = exp.run()
    print_summary(console, summary)
    if summary.interrupted:
        return 130
    if summary.aborted or summary.error:
        return 1
    return 0


def _results(args: argparse.Namespace) -> int:
    from rich.console import Console

    from mrswarm.results import ResultsError, rebuild_results
    from mrswarm.summary_table import print_summary

    console = Console()
    path = Path(args.run_dir)
    try:
        if path.is_file():  # a recording (docs/recording.md): its run folder first
            from mrswarm.recorder.cli import results_from_recording

            path = results_from_recording(path, Path(args.out) if args.out else None)
        elif args.out:
            raise ResultsError("--out is for a recording (run.mcap); a run folder's results go into the folder")
        summary = rebuild_results(path)
    except ResultsError as exc:
        console.print(f"[red]error:[/] {exc}", highlight=False)
        return 2
    print_summary(console, summary)
    return 1 if summary.error else 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="mrswarm", description="Mixed-reality drone-swarm experiments over cellular edge networks.")
    ap.add_argument("--version", action="version", version=f"mrswarm {_version()}")
    sub = ap.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("run", help="run a scenario (one process per virtual UAV) and write a results folder")
    p.add_argument("scenario", help="scenario YAML, e.g. scenarios/coverage.yaml")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scenario field before validation, e.g. --set uavs.1.rtf=0.4 (repeatable)")
    p.add_argument("--out", default="results", help="folder for run results (default: ./results)")
    p.add_argument("--no-live", action="store_true", help="plain progress lines instead of the live display")
    p.add_argument("--log-level", default="INFO", help="log level of the UAV processes (their logs go to <run>/logs)")
    p.add_argument("--runtime", choices=["process", "docker"], default=None,
                   help="one OS process or one Docker container per virtual UAV (default: the scenario's, else process)")
    p.add_argument("--no-record", action="store_true", help="no flight recording (<run>/run.mcap, docs/recording.md)")
    p.set_defaults(func=_run)

    p = sub.add_parser("results", help="rebuild summary.json and the figures of a run folder (or of a recording, run.mcap)")
    p.add_argument("run_dir", help="a folder written by `mrswarm run`, e.g. results/coverage-20250101-120000, or its run.mcap")
    p.add_argument("--out", default=None, help="with a recording: the folder to rebuild the run in (default: run-export)")
    p.set_defaults(func=_results)

    p = sub.add_parser("agent", help="run the swarm agent against a flight controller (real UAV, SITL)", add_help=False)
    p.set_defaults(func=lambda a: _delegate("uav_stack.runtime", "agent_main", a.rest))
    p = sub.add_parser("fcu", help="a standalone virtual flight controller speaking MAVLink over UDP", add_help=False)
    p.set_defaults(func=lambda a: _delegate("uav_stack.fcu.__main__", "main", a.rest))
    p = sub.add_parser("router", help="a Zenoh rendezvous/edge router", add_help=False)
    p.set_defaults(func=lambda a: _delegate("discovery.rendezvous", "main", a.rest))
    p = sub.add_parser("deploy", help="images, containers and Docker Swarm stacks (base-image, build, ps, logs, down, swarm)",
                       add_help=False)
    p.set_defaults(func=lambda a: _delegate("mrswarm.deploy_cli", "main", a.rest))

    p = sub.add_parser("netem", help="network impairments: presets, change a running swarm, status (docs/netem.md)",
                       add_help=False)
    p.set_defaults(func=lambda a: _delegate("mrswarm.netem_cli", "main", a.rest))

    p = sub.add_parser("discovery", help="discovery server (serve), registry (nodes), probe node, keygen", add_help=False)
    p.set_defaults(func=lambda a: _delegate("discovery.cli", "main", a.rest))
    p = sub.add_parser("netlab", help="routed network-namespace lab without multicast (up/down/list; root)", add_help=False)
    p.set_defaults(func=lambda a: _delegate("discovery.netlab", "main", a.rest))

    p = sub.add_parser("world", help="the world service of a scenario, at the edge: virtual sensors, hazards, airspace "
                                     "(docs/world.md)", add_help=False)
    p.set_defaults(func=lambda a: _delegate("mrswarm.world_cli", "main", a.rest))

    p = sub.add_parser("gcs", help="ground station: watch, telemetry, overrides, record (docs/gcs.md)", add_help=False)
    p.set_defaults(func=lambda a: _delegate("mrswarm.gcs.cli", "main", a.rest))
    p = sub.add_parser("export", help="a recording (run.mcap) as a run folder of CSVs or as JSON Lines (docs/recording.md)",
                       add_help=False)
    p.set_defaults(func=lambda a: _delegate("mrswarm.recorder.cli", "export_main", a.rest))
    p = sub.add_parser("replay", help="republish a recording under its own swarm name, for gcs watch/web and Foxglove",
                       add_help=False)
    p.set_defaults(func=lambda a: _delegate("mrswarm.recorder.cli", "replay_main", a.rest))

    p = sub.add_parser("keys", help="the swarm's certificates: init, issue, bundle, revoke, rotate, list (docs/security.md)",
                       add_help=False)
    p.set_defaults(func=lambda a: _delegate("mrswarm.keys_cli", "main", a.rest))

    args, rest = ap.parse_known_args(argv)
    if args.command in ("agent", "fcu", "router", "deploy", "netem", "discovery", "netlab", "gcs", "export", "replay", "keys",
                        "world"):
        args.rest = rest
    elif rest:
        ap.error(f"unrecognized arguments: {' '.join(rest)}")
    return int(args.func(args) or 0)


def _delegate(module: str, func: str, argv: list[str]) -> int:
    import importlib

    return int(getattr(importlib.import_module(module), func)(argv) or 0)


def _version() -> str:
    from swarmnet.version import __version__

    return __version__


if __name__ == "__main__":
    sys.exit(main())
