"""The ``mrswarm`` command: one CLI, a subcommand per job.

Heavy imports happen inside each subcommand, so ``mrswarm agent`` on a companion computer
does not load matplotlib.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

# exit codes of `mrswarm run` (docs/reliability.md)
EXIT_OK = 0  # the run completed: no collision, no incident
EXIT_FAILED = 1  # the runner gave up (aborted), nothing was recorded, or the records are incomplete (degraded)
EXIT_USAGE = 2  # bad input: the scenario, an override, --out, or a fleet too large for this machine
EXIT_SAFETY = 3  # the run completed, with collisions or incidents (a UAV fell or hit the ground)
EXIT_SATURATED = 4  # the run completed, but the machine could not keep up: its figures measure the host (summary.saturated)
# 128 + N: stopped by signal N (130 Ctrl-C, 143 SIGTERM, 129 SIGHUP)


def _run(args: argparse.Namespace) -> int:
    try:
        from mrswarm.run.signals import StopSignals

        signals = StopSignals().install()  # from the start: a Ctrl-C is never a traceback
    except KeyboardInterrupt:  # came before the handler
        return 130
    from rich.console import Console

    console = Console()
    try:
        return _run_with(args, console, signals)
    finally:
        signals.restore()
        if signals.hangup:  # the terminal is gone: what is still buffered for it would fail at exit
            _detach_from_terminal()


def _detach_from_terminal() -> None:
    import os

    try:
        fd = os.open(os.devnull, os.O_WRONLY)
        os.dup2(fd, 1)
        os.dup2(fd, 2)
        os.close(fd)
    except OSError:
        pass


def _run_with(args: argparse.Namespace, console: Any, signals: Any) -> int:
    from mrswarm.results.summary_table import print_summary
    from mrswarm.run.resources import check_resources
    from mrswarm.scenario import ScenarioError, load_scenario

    notes: list[str] = []
    try:
        scn = load_scenario(args.scenario, args.set + ([f"runtime={args.runtime}"] if args.runtime else []), notes)
    except ScenarioError as exc:
        console.print(f"[red]error:[/] {exc}", highlight=False, soft_wrap=True)
        return EXIT_USAGE
    for note in notes:  # a shortened mission: what of its schedule it leaves out
        console.print(f"[yellow]note:[/] {args.scenario}: {note}", highlight=False, soft_wrap=True)
    problem = check_resources(scn)
    if problem and not args.force:
        console.print(f"[red]error:[/] {args.scenario}: {problem}", highlight=False, soft_wrap=True)
        return EXIT_USAGE
    if problem:
        console.print(f"[yellow]warning:[/] {problem} (--force)", highlight=False, soft_wrap=True)
    if signals.requested:
        return signals.exit_code
    from mrswarm.run.experiment import Experiment  # heavy (zenoh, numpy): only once the input is known to be good

    try:
        exp = Experiment(scn, Path(args.out), console=console, live=not args.no_live, log_level=args.log_level,
                         record=not args.no_record, signals=signals)
    except RuntimeError as exc:  # a runtime that cannot start (no docker engine, no image, ...)
        console.print(f"[red]error:[/] {exc}", highlight=False, soft_wrap=True)
        return EXIT_USAGE
    except OSError as exc:  # --out read-only, a file, full...
        console.print(f"[red]error:[/] --out {args.out}: cannot create the results folder there: "
                      f"{exc.strerror or exc}" + (f" ({exc.filename})" if exc.filename else ""), highlight=False, soft_wrap=True)
        return EXIT_USAGE
    summary = exp.run()
    try:
        print_summary(console, summary)
    except OSError:  # the terminal is gone (SIGHUP): summary.json holds it
        pass
    if signals.requested:  # stopped (or hurried) by a signal: 128 + its number
        return signals.exit_code
    if summary.aborted or summary.error:
        return EXIT_FAILED
    if summary.safety_events:
        return EXIT_SAFETY
    if summary.degraded:  # a full or failing disk lost records: the summary's `degraded` says which
        return EXIT_FAILED
    if summary.saturated:
        return EXIT_SATURATED
    return EXIT_OK


def _results(args: argparse.Namespace) -> int:
    from rich.console import Console

    from mrswarm.results.summarise import ResultsError, rebuild_results, results_from_recording
    from mrswarm.results.summary_table import print_summary

    console = Console()
    if args.run_dir is None:  # no folder named: the recent runs, to pick one
        from mrswarm.results.summarise import list_runs

        return list_runs(console, Path("results"))
    path = Path(args.run_dir)
    try:
        if path.is_file():  # a recording (docs/recording.md): its run folder first
            path = results_from_recording(path, Path(args.out) if args.out else None)
        elif args.out:
            raise ResultsError("--out is for a recording (run.mcap); a run folder's results go into the folder")
        summary = rebuild_results(path)
    except ResultsError as exc:
        console.print(f"[red]error:[/] {exc}", highlight=False, soft_wrap=True)
        return 2
    except KeyboardInterrupt:
        console.print("[yellow]interrupted[/]: summary.json was not rebuilt")
        return 130
    print_summary(console, summary)
    return 1 if summary.error else 0


# Subcommands that hand their arguments to another module's entry point:
# name -> (help, module, function taking argv).
DELEGATED: dict[str, tuple[str, str, str]] = {
    "agent": ("run the swarm agent against a flight controller (real UAV, SITL)", "uav_stack.runtime", "agent_main"),
    "fcu": ("a standalone virtual flight controller speaking MAVLink over UDP", "uav_stack.fcu.__main__", "main"),
    "preflight": ("check a flight controller for what the agent needs (docs/fcu.md)", "mrswarm.cli.preflight", "main"),
    "router": ("a Zenoh rendezvous/edge router", "discovery.rendezvous", "main"),
    "deploy": ("images, containers and Docker Swarm stacks (base-image, build, ps, logs, down, swarm)",
               "mrswarm.cli.deploy", "main"),
    "netem": ("network impairments: presets, change a running swarm, status (docs/netem.md)", "mrswarm.cli.netem", "main"),
    "discovery": ("discovery server (serve), registry (nodes), probe node, keygen", "discovery.cli", "main"),
    "netlab": ("routed network-namespace lab without multicast (up/down/list; root)", "discovery.netlab", "main"),
    "world": ("the world service of a scenario, at the edge: virtual sensors, hazards, airspace (docs/world.md)",
              "mrswarm.cli.world", "main"),
    "gcs": ("ground station: watch, telemetry, overrides, record (docs/gcs.md)", "mrswarm.gcs.cli", "main"),
    "export": ("a recording (run.mcap) as a run folder of CSVs or as JSON Lines (docs/recording.md)",
               "mrswarm.recorder.cli", "export_main"),
    "replay": ("republish a recording under its own swarm name, for gcs watch/web and Foxglove",
               "mrswarm.recorder.cli", "replay_main"),
    "sweep": ("a campaign: a scenario over a grid of overrides and seeds, one table with confidence intervals, plots "
              "(docs/campaigns.md)", "mrswarm.sweep.cli", "main"),
    "new": ("write a new package from a template: new behaviour NAME (docs/sdk.md)", "mrswarm.cli.scaffold", "main"),
    "keys": ("the swarm's certificates: init, issue, bundle, revoke, rotate, list (docs/security.md)",
             "mrswarm.cli.keys", "main"),
}


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
    p.add_argument("--force", action="store_true", help="run even if the fleet looks too large for this machine")
    p.add_argument("--no-record", action="store_true", help="no flight recording (<run>/run.mcap, docs/recording.md)")
    p.set_defaults(func=_run)

    p = sub.add_parser("results", help="rebuild summary.json and the figures of a run folder (or of a recording, run.mcap); "
                                       "alone: list the recent runs in ./results")
    p.add_argument("run_dir", nargs="?", default=None,
                   help="a folder written by `mrswarm run`, e.g. results/coverage-20250101-120000, or its run.mcap")
    p.add_argument("--out", default=None, help="with a recording: the folder to rebuild the run in (default: run-export)")
    p.set_defaults(func=_results)

    for name, (text, module, func) in DELEGATED.items():  # each parses its own arguments
        p = sub.add_parser(name, help=text, add_help=False)
        p.set_defaults(func=lambda a, module=module, func=func: _delegate(module, func, a.rest))

    args, rest = ap.parse_known_args(argv)
    if args.command in DELEGATED:
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
