"""``mrswarm export`` and ``mrswarm replay``: what a user does with a recording (docs/recording.md)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2


def _err(msg: str) -> int:
    print(f"error: {msg}", file=sys.stderr)
    return EXIT_USAGE


def export_main(argv: list[str] | None = None) -> int:
    from mrswarm.recorder.export import ExportError, default_out, export_csv, export_jsonl, list_topics

    ap = argparse.ArgumentParser(prog="mrswarm export",
                                 description="Export a recording (MCAP): a run folder, JSON Lines, or the list of its topics.")
    ap.add_argument("file", help="a recording, e.g. results/coverage-20260101-120000/run.mcap")
    what = ap.add_mutually_exclusive_group(required=True)
    what.add_argument("--csv", action="store_true", help="uav<N>.csv trajectories and the run's files (for `mrswarm results`)")
    what.add_argument("--jsonl", action="store_true", help="the ground station's JSON Lines (`mrswarm gcs plot` draws it)")
    what.add_argument("--topics", action="store_true", help="list the recording's channels: topic, schema, messages")
    ap.add_argument("--out", default=None, help="a folder (--csv; default <stem>-export) or a file (--jsonl; default .jsonl)")
    args = ap.parse_args(argv)
    path = Path(args.file)
    try:
        if args.topics:
            info = list_topics(path)
            width = max((len(t) for t, _, _ in info["topics"]), default=5)
            for topic, schema, n in sorted(info["topics"]):
                print(f"{topic:<{width}}  {schema:<26} {n:>8}")
            print(f"{len(info['topics'])} topics, {info['messages']} messages")
        elif args.csv:
            info = export_csv(path, Path(args.out) if args.out else default_out(path))
            values = f", {info['values']} recorded values" if info["values"] else ""
            print(f"{info['out']}: {info['uavs']} UAVs, {info['rows']} rows{values}; {', '.join(info['files'])}")
        else:
            info = export_jsonl(path, Path(args.out) if args.out else path.with_suffix(".jsonl"))
            print(f"{info['out']}: {info['messages']} messages")
    except ExportError as exc:
        return _err(str(exc))
    if info["error"]:
        print(f"note: the recording ends early ({info['error']}): its writer was killed; everything before is exported")
    return EXIT_OK


def replay_main(argv: list[str] | None = None) -> int:
    from mrswarm.recorder.replay import ReplayError, parse_offset, replay

    ap = argparse.ArgumentParser(prog="mrswarm replay",
                                 description="Republish a recording into a Zenoh session under its own swarm name: "
                                             "`gcs watch`, `gcs web` and Foxglove show it like a live run.")
    ap.add_argument("file", help="a recording (MCAP)")
    ap.add_argument("--speed", type=float, default=1.0, help="playback speed (default 1; 4 = four times faster)")
    ap.add_argument("--from", dest="start", default="0s", help="start this far into the recording: 30s, 2m, 90 (default 0s)")
    ap.add_argument("--to", dest="end", default=None, help="stop this far into the recording (default: its end)")
    ap.add_argument("--swarm", default=None, help="the replay's swarm name (default replay-<recorded>; never the recorded one)")
    ap.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                    help="publish through this Zenoh router (repeatable; default: start one on --listen)")
    ap.add_argument("--listen", default="tcp/127.0.0.1:7448", help="its own router, without --connect (default %(default)s)")
    ap.add_argument("--run-dir", default=None, help="write network.json here, so `mrswarm gcs ... --run DIR` finds the replay")
    ap.add_argument("--quiet", action="store_true")
    args = ap.parse_args(argv)
    try:
        if not args.speed > 0:
            raise ReplayError("--speed must be > 0")
        n = replay(Path(args.file), speed=args.speed, start=parse_offset(args.start, "--from"),
                   end=parse_offset(args.end, "--to") if args.end is not None else None, swarm=args.swarm,
                   connect=tuple(args.connect), listen=args.listen, run_dir=Path(args.run_dir) if args.run_dir else None,
                   quiet=args.quiet)
    except ReplayError as exc:
        return _err(str(exc))
    except KeyboardInterrupt:
        return 130
    if not args.quiet:
        print(f"replayed {n} messages")
    return EXIT_OK

