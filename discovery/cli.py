"""``mrswarm discovery ...``: the discovery server, registry queries, a probe node, keys.

    mrswarm discovery serve --listen <edge-address>:7450 --keys keys.txt
    mrswarm discovery nodes --server 10.0.0.2:7450 --swarm alpha --key-file alpha.key [--json]
    mrswarm discovery probe --server 10.0.0.2:7450 --swarm alpha --id 7 --key-file alpha.key
    mrswarm discovery keygen > alpha.key
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

USAGE = __doc__


def nodes_main(argv: list[str]) -> int:
    from discovery.client import QueryTimeout, query_registry

    ap = argparse.ArgumentParser(prog="mrswarm discovery nodes", description="list a swarm's nodes from the discovery server")
    ap.add_argument("--server", required=True, help="HOST:PORT")
    ap.add_argument("--swarm", required=True)
    ap.add_argument("--key", default=None)
    ap.add_argument("--key-file", default=None)
    ap.add_argument("--timeout", type=float, default=1.0)
    ap.add_argument("--json", action="store_true", help="machine-readable output (with the server's counters)")
    args = ap.parse_args(argv)
    key = Path(args.key_file).read_text().strip() if args.key_file else args.key
    if not key:
        ap.error("--key or --key-file is required")
    try:
        rows, stats = query_registry(args.server, args.swarm, key, timeout=args.timeout)
    except (QueryTimeout, ValueError, OSError) as exc:
        print(f"mrswarm discovery nodes: error: {exc}", file=sys.stderr)
        return 1
    rows.sort(key=lambda r: (r.entry.role, r.entry.node))
    if args.json:
        print(json.dumps({"nodes": [r.to_dict() for r in rows], "server": stats}, indent=2))
        return 0
    now = time.time()
    print(f"swarm {args.swarm}: {len(rows)} nodes")
    for r in rows:
        e = r.entry
        print(f"  {e.role:8s} {e.node:5d}  {e.realm:8s} {e.software:16s} zid {e.zid_hex:32s} "
              f"seen {now - r.last_seen:4.1f} s ago  from {r.address}  {' '.join(e.locators)}")
    return 0


def keygen_main(argv: list[str]) -> int:
    from discovery.protocol import new_key

    argparse.ArgumentParser(prog="mrswarm discovery keygen", description="print a new random swarm key").parse_args(argv)
    print(new_key())
    return 0


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(USAGE)
        return 0 if argv else 2
    cmd, rest = argv[0], argv[1:]
    if cmd == "serve":
        from discovery.server import main as serve_main

        return serve_main(rest)
    if cmd == "nodes":
        return nodes_main(rest)
    if cmd == "probe":
        from discovery.probe import main as probe_main

        return probe_main(rest)
    if cmd == "keygen":
        return keygen_main(rest)
    print(f"mrswarm discovery: unknown command {cmd!r}\n{USAGE}", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
