"""A UAV's Zenoh runtimes, the lean ones a UAV process sets against Zenoh's defaults, side by side.

Runs ``benchmarks/transport.py`` alternately with the lean runtime a UAV process sets
(``swarmnet.connectivity.LEAN_ZENOH_RUNTIME``) and with ``ZENOH_RUNTIME='()'`` (Zenoh's defaults),
or with the runtimes given by ``--runtime LABEL=VALUE`` (repeatable, in that order), ``--rounds``
rounds, and merges the rows into ``<tag>.json/.csv`` with a plot ``<tag>.png``: transport age
p50 / p99 and CPU per agent of each swarmnet transport under each runtime. The router is
Zenoh's defaults in all (it never calls ``lean_zenoh_runtime``).

    python benchmarks/zenoh_runtime.py --n 25 --rounds 2 --out benchmarks/results   # about 6 minutes
    python benchmarks/zenoh_runtime.py --runtime 'rx1=(rx: (worker_threads: 1))' --runtime 'lean=(rx: (handover: app), ...)'
"""

from __future__ import annotations

import argparse
import csv
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from benchmarks.output import write_results  # noqa: E402
from swarmnet.connectivity import LEAN_ZENOH_RUNTIME  # noqa: E402

SIDES = (("lean", None), ("Zenoh's defaults", "()"))  # (label, ZENOH_RUNTIME; None: the lean default)
RUN_TIMEOUT_S = 900.0


def run_transport(n: int, transports: list[str], env_value: str | None, out: Path) -> list[dict[str, Any]]:
    env = {k: v for k, v in os.environ.items() if k != "ZENOH_RUNTIME"}
    if env_value is not None:
        env["ZENOH_RUNTIME"] = env_value
    subprocess.run([sys.executable, str(ROOT / "benchmarks" / "transport.py"), "--sizes", str(n), "--transports",
                    *transports, "--rounds", "1", "--out", str(out), "--tag", "run"], cwd=ROOT, env=env, check=True,
                   timeout=RUN_TIMEOUT_S)
    with open(out / "run.csv") as f:
        return list(csv.DictReader(f))


def plot(rows: list[dict[str, Any]], transports: list[str], sides: list[tuple[str, str | None]], path: Path,
         title: str) -> None:
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6))
    for ax, (field, label) in zip(axes, (("age_p50_ms", "transport age p50, ms"), ("age_p99_ms", "transport age p99, ms"),
                                         ("cpu_pct_median", "CPU per agent, % of a core")), strict=True):
        for i, tr in enumerate(transports):
            for j, (side, _) in enumerate(sides):
                ys = [float(r[field]) for r in rows if r["transport"] == tr and r["runtime"] == side]
                dx = 0.3 * (j - (len(sides) - 1) / 2) / max(len(sides) - 1, 1)
                ax.scatter([i + dx] * len(ys), ys, color=f"C{j}", label=side if i == 0 else None)
        ax.set_xticks(range(len(transports)), transports)
        ax.set_title(label, fontsize=9)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=25, help="agents")
    ap.add_argument("--transports", nargs="+", default=["swarmnet-client", "swarmnet-edge"])
    ap.add_argument("--rounds", type=int, default=2, help="rounds, each flies every runtime in turn")
    ap.add_argument("--runtime", action="append", default=[], metavar="LABEL=VALUE",
                    help="a ZENOH_RUNTIME to fly (repeatable; default: the lean one and Zenoh's defaults)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    ap.add_argument("--tag", default="rx1_transport")
    args = ap.parse_args(argv)
    sides: list[tuple[str, str | None]] = list(SIDES)
    if args.runtime:
        try:
            sides = [(label, value) for label, value in (spec.split("=", 1) for spec in args.runtime)]
        except ValueError:
            ap.error("--runtime takes LABEL=VALUE")
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="mrswarm-zrt-") as tmp:
        for rnd in range(args.rounds):
            for side, env_value in sides:
                for row in run_transport(args.n, args.transports, env_value, Path(tmp) / f"{rnd}-{len(rows)}"):
                    rows.append({"runtime": side, "zenoh_runtime": env_value or LEAN_ZENOH_RUNTIME, "pair": rnd, **row})
                    print(f"pair {rnd}, {side}: {row['transport']} age p50 / p99 {row['age_p50_ms']} / {row['age_p99_ms']} ms, "
                          f"CPU {row['cpu_pct_median']} %", flush=True)
    out = Path(args.out)
    write_results(out, args.tag, {"args": vars(args), "cores": os.cpu_count(), "rows": rows}, rows)
    plot(rows, args.transports, sides, out / f"{args.tag}.png",
         f"N = {args.n}, a UAV's Zenoh runtimes: {' / '.join(s for s, _ in sides)}, {args.rounds} alternated rounds")
    return 0


if __name__ == "__main__":
    sys.exit(main())
