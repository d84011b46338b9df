"""``mrswarm sweep``: fly a campaign (a campaign file, or a scenario with ``--grid``), or rebuild its report.

```
mrswarm sweep campaigns/coverage_n.yaml                       # the campaign file's grid and seeds
mrswarm sweep scenarios/coverage.yaml --grid fleet.count=5,10,20 --seeds 5 --set duration=60
mrswarm sweep campaigns/coverage_n.yaml --plan                # what it would fly, what is complete already
mrswarm sweep --report results/coverage_n                     # tables and plots from the folder alone
```

Exit codes: 0 every run complete, 1 some failed (their runner gave up), 2 bad input (the
campaign, a grid value, a scenario, a folder of another campaign), 128 + N stopped by signal N.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from uav_stack.cli_args import ArgumentParser

EXIT_USAGE = 2


def parser() -> argparse.ArgumentParser:
    ap = ArgumentParser(prog="mrswarm sweep",
                        description="Fly a scenario over a grid of overrides and seeds; one results table with confidence "
                                    "intervals, and plots (docs/campaigns.md).")
    ap.add_argument("file", nargs="?", help="a campaign file (YAML with `scenario:` and `grid:`), or a scenario file with --grid")
    ap.add_argument("--grid", action="append", default=[], metavar="KEY=V1,V2,...",
                    help="a swept override, e.g. --grid fleet.count=5,10,20 (repeatable; any `mrswarm run --set` key)")
    ap.add_argument("--seeds", default=None, help="a number of seeds (5: seeds 0..4) or a list (7,11,13)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="an override of every run (repeatable)")
    ap.add_argument("--out", default=None, help="the campaign folder (default: results/<campaign name>); the same --out resumes")
    ap.add_argument("--parallel", default=None, metavar="N|auto",
                    help="fly up to N runs at once, each only when the machine has room for it (default 1)")
    ap.add_argument("--on", choices=["local", "swarm"], default="local",
                    help="where the runs fly: this machine, or the Docker Swarm that DOCKER_HOST manages (one job per run; "
                         "the campaign folder must be shared by every node)")
    ap.add_argument("--image", default=None, help="with --on swarm: the stack image of the jobs (default: mrswarm:<version>)")
    ap.add_argument("--retry-failed", action="store_true", help="fly again the runs whose runner gave up")
    ap.add_argument("--no-record", action="store_true", help="no flight recording (run.mcap) in the runs")
    ap.add_argument("--force", action="store_true", help="fly fleets that look too large for this machine (mrswarm run --force)")
    ap.add_argument("--no-live", action="store_true", help="plain lines instead of the progress bar")
    ap.add_argument("--log-level", default="INFO", help="log level of the UAV processes")
    ap.add_argument("--plan", action="store_true", help="list the runs and what is complete already, fly nothing")
    ap.add_argument("--report", metavar="DIR", default=None,
                    help="rebuild the tables and plots of a campaign folder, fly nothing")
    ap.add_argument("--metrics", default=None, help="with --report: the metrics to plot, comma-separated (summary.json paths)")
    return ap


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        from mrswarm.run.signals import StopSignals

        signals = StopSignals().install()
    except KeyboardInterrupt:
        return 130
    try:
        return _main(argv, signals)
    finally:
        signals.restore()


def _main(argv: list[str], signals: Any) -> int:
    from rich.console import Console

    args = parser().parse_args(argv)
    console = Console()
    err = Console(stderr=True)
    if args.report is not None:
        return _report(args, console, err)
    if args.file is None:
        err.print("[red]error:[/] name a campaign file, or a scenario with --grid (or --report DIR)", highlight=False,
                  soft_wrap=True)
        return EXIT_USAGE
    from mrswarm.sweep.campaign import CampaignError

    try:
        plan, out, parallel = _plan(args)
    except CampaignError as exc:
        err.print(f"[red]error:[/] {exc}", highlight=False, soft_wrap=True)
        return EXIT_USAGE
    if args.plan:
        return _show_plan(console, plan, out)
    from mrswarm.sweep.launch import RunOptions
    from mrswarm.sweep.runner import Sweep, resume_command

    opts = RunOptions(record=plan.campaign.record and not args.no_record, force=args.force, log_level=args.log_level)
    resume = resume_command([a for a in argv if a != "--retry-failed"] + ([] if args.out else ["--out", str(out)]))
    launcher = None
    if args.on == "swarm":
        from deploy.dockerutil import DeployError
        from deploy.images import image_tag
        from mrswarm.sweep.swarm_jobs import SwarmJobs

        try:
            launcher = SwarmJobs(out, plan.scenario_path, args.image or image_tag(), opts)
        except DeployError as exc:
            err.print(f"[red]error:[/] {exc}", highlight=False, soft_wrap=True)
            return EXIT_USAGE
    if parallel is None:
        parallel = "auto" if args.on == "swarm" else 1
    sweep = Sweep(plan, out, console, parallel=parallel, retry_failed=args.retry_failed, opts=opts, live=not args.no_live,
                  signals=signals, resume_command=resume, err=err, launcher=launcher)
    return sweep.run()


def _plan(args: argparse.Namespace) -> tuple[Any, Path, int | str | None]:
    import yaml

    from mrswarm.sweep.campaign import (
        CampaignError,
        campaign_from_flags,
        is_campaign_file,
        merge_flags,
        parse_campaign,
        parse_seeds,
        plan_campaign,
    )
    from mrswarm.sweep.table import metric_problem

    path = Path(args.file)
    seeds = parse_seeds(args.seeds) if args.seeds is not None else None
    if is_campaign_file(path):
        from mrswarm.sweep.campaign import _read_text

        data = yaml.safe_load(_read_text(path))
        merge_flags(data, args.grid, seeds, args.set)
        source: Path | None = path
        where = str(path)
    else:
        if not path.is_file():
            raise CampaignError(f"{path}: no such file")
        if not args.grid and seeds is None:
            raise CampaignError(f"{path}: a scenario file: give --grid KEY=V1,V2 and/or --seeds N (or a campaign file)")
        data = campaign_from_flags(str(path.resolve()), args.grid, seeds, args.set)
        source, where = None, "sweep"
    if args.parallel is not None:
        data["parallel"] = args.parallel if args.parallel == "auto" else _int(args.parallel, "--parallel")
    campaign = parse_campaign(data, where)
    for i, m in enumerate(campaign.metrics or []):
        problem = metric_problem(m)
        if problem:
            raise CampaignError(f"{where}: metrics.{i}: {problem}")
    plan = plan_campaign(campaign, source, where)
    if source is None and campaign.name is None:
        from dataclasses import replace

        plan = replace(plan, name=f"{plan.name}-sweep")
    out = Path(args.out) if args.out else Path("results") / plan.name
    return plan, out, campaign.parallel


def _int(text: str, flag: str) -> int:
    from mrswarm.sweep.campaign import CampaignError

    try:
        return int(text)
    except ValueError:
        raise CampaignError(f"{flag} {text!r}: a number of runs, or auto") from None


def _show_plan(console: Any, plan: Any, out: Path) -> int:
    from rich.table import Table

    from mrswarm.sweep.progress import Estimator, duration
    from mrswarm.sweep.slots import slot_dir, status

    est = Estimator()
    table = Table(title=f"{plan.name}: {len(plan.slots)} runs into {out}", title_justify="left", show_edge=False)
    for col in ("run", "folder", "state"):
        table.add_column(col)
    left = 0.0
    for s in plan.slots:
        st = status(slot_dir(out, s.name))
        state = st.state.value + (f" ({st.interrupted} interrupted)" if st.interrupted else "")
        if st.record is not None and st.record.digest != s.digest:
            state = "[red]another scenario[/]"
        if st.state.value == "pending":
            left += est.predict(s)
        table.add_row(s.label, f"runs/{s.name}", state)
    console.print(table)
    console.print(f"to fly: about {duration(left)} one at a time", highlight=False)
    return 0


def _report(args: argparse.Namespace, console: Any, err: Any) -> int:
    from mrswarm.sweep.report import build_report
    from mrswarm.sweep.slots import RUNS
    from mrswarm.sweep.table import metric_problem

    folder = Path(args.report)
    if not (folder / RUNS).is_dir():
        err.print(f"[red]error:[/] --report {folder}: not a campaign folder (no {RUNS}/ in it)", highlight=False,
                  soft_wrap=True)
        return EXIT_USAGE
    metrics = [m.strip() for m in args.metrics.split(",") if m.strip()] if args.metrics else None
    for m in metrics or []:
        problem = metric_problem(m)
        if problem:
            err.print(f"[red]error:[/] --metrics: {problem}", highlight=False, soft_wrap=True)
            return EXIT_USAGE
    from mrswarm.sweep.runner import results_line

    paths = build_report(folder, console=console, metrics=metrics)
    if paths:
        console.print(results_line(folder, paths), highlight=False, soft_wrap=True)
    return 0
