"""Security benchmark: CPU per virtual UAV and pose age with mutual TLS and access control, on against off.

For each swarm size N and each network configuration it flies the scaling benchmark's
random-coverage mission (``benchmarks/scale.py``: every UAV keeps moving and exchanging poses at
10 Hz) twice, ``network.security`` ``mtls`` and ``off``, back to back, in alternating order from
one N to the next so that neither side always gets the fresher machine. It measures every
process over ``--window`` seconds after ``--warmup`` (the scaling benchmark's sampler) and
writes, per N and configuration, the two side by side:

* CPU per UAV process (median and max over the UAVs, % of one core) and the overhead of
  security in % of the insecure median (the target: at most +10 %);
* pose age at the receivers (p50, p99, ms) and pose loss;
* the edge router's CPU (on the data path in client mode: TLS and access control on both flows);
* the refusals the run counted (none expected: nobody attacks here).

    python benchmarks/security.py --sizes 10 25 50 --out benchmarks/results

writes ``security.json``, ``security.csv`` and ``security.png``. The default configurations are
the default network (discovery, peer mesh, direct poses) and client mode through the edge router.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any, Literal

import psutil
from msgspec.structs import replace
from rich.console import Console

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.output import write_results  # noqa: E402
from benchmarks.scale import CONFIGS, run_size  # noqa: E402
from mrswarm.scenario import Scenario, Security  # noqa: E402

SecurityMode = Literal["off", "mtls"]
MODES: tuple[SecurityMode, ...] = ("off", "mtls")
TARGET_OVERHEAD_PCT = 10.0  # at most +10 % CPU per UAV (issue 9)


def with_security(scn: Scenario, mode: SecurityMode) -> Scenario:
    return replace(scn, name=f"{scn.name}-{mode}", network=replace(scn.network, security=Security(mode=mode)))


def measure(n: int, config: str, mode: SecurityMode, args: argparse.Namespace, console: Console) -> dict[str, Any]:
    """One run (``benchmarks/scale.py``'s run_size on its scenario with ``network.security.mode``)."""
    row = run_size(n, config, args, console, adapt=lambda scn: with_security(scn, mode))
    summary = json.loads((Path(row["run_dir"]) / "summary.json").read_text())
    sec = summary.get("security", {})
    row["security"] = sec.get("mode")
    row["refused"] = sum(sec.get("refused_by_uavs", {}).values()) + sum(sec.get("refused_by_router", {}).values())
    if row["security"] != mode:
        raise SystemExit(f"N={n} {config}: the run says security {row['security']!r}, asked for {mode!r}")
    return row


def side_by_side(off: dict[str, Any], on: dict[str, Any]) -> dict[str, Any]:
    def pct(a: float | None, b: float | None) -> float | None:
        if a is None or b is None or not a or math.isnan(a) or math.isnan(b):
            return None
        return round(100.0 * (b - a) / a, 1)

    out: dict[str, Any] = {"n": off["n"], "config": off["config"]}
    for key in ("cpu_pct_median", "cpu_pct_max", "rss_mb_median", "transport_age_p50_ms", "transport_age_p99_ms",
                "use_age_p50_ms", "pose_loss", "router_cpu_pct", "rtf_min", "collisions", "refused"):
        out[f"{key}_off"], out[f"{key}_on"] = off.get(key), on.get(key)
    out["cpu_overhead_pct"] = pct(off.get("cpu_pct_median"), on.get("cpu_pct_median"))  # None: a run aborted
    out["within_target"] = out["cpu_overhead_pct"] is not None and out["cpu_overhead_pct"] <= TARGET_OVERHEAD_PCT
    return out


def plot(rows: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 3, figsize=(15, 4.2))
    for i, cfg in enumerate(dict.fromkeys(r["config"] for r in rows)):
        rs = sorted((r for r in rows if r["config"] == cfg), key=lambda r: r["n"])
        ns = [r["n"] for r in rs]
        c = f"C{i}"
        ax[0].plot(ns, [r["cpu_pct_median_off"] for r in rs], "o:", color=c, label=f"{cfg} off")
        ax[0].plot(ns, [r["cpu_pct_median_on"] for r in rs], "o-", color=c, label=f"{cfg} mTLS + ACL")
        ax[1].plot(ns, [r["cpu_overhead_pct"] for r in rs], "o-", color=c, label=cfg)
        ax[2].plot(ns, [r["transport_age_p50_ms_off"] for r in rs], "o:", color=c, label=f"{cfg} p50 off")
        ax[2].plot(ns, [r["transport_age_p50_ms_on"] for r in rs], "o-", color=c, label=f"{cfg} p50 on")
        ax[2].plot(ns, [r["transport_age_p99_ms_on"] for r in rs], "x--", color=c, alpha=0.6, label=f"{cfg} p99 on")
    ax[0].set_title("CPU per UAV process, median (% of one core)")
    ax[1].axhline(TARGET_OVERHEAD_PCT, color="r", ls=":", label=f"target +{TARGET_OVERHEAD_PCT:g} %")
    ax[1].axhline(0.0, color="k", lw=0.5)
    ax[1].set_title("CPU overhead of security (% of the insecure median)")
    ax[2].set_yscale("log")
    ax[2].set_title("pose age at the receivers (ms)")
    for a in ax:
        a.set_xlabel("virtual UAVs (N)")
        a.legend(fontsize=7)
        a.grid(alpha=0.3)
    fig.suptitle(f"mrswarm security on vs off, process runtime, one run per cell, {psutil.cpu_count()} cores")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[10, 25, 50])
    ap.add_argument("--warmup", type=float, default=8.0, help="seconds after the mission starts before measuring")
    ap.add_argument("--window", type=float, default=30.0, help="measurement window, s")
    ap.add_argument("--configs", nargs="+", choices=list(CONFIGS), default=["discovery-direct", "client-edge"],
                    help="network configurations, each flown with security on and off at every N")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    ap.add_argument("--replot", action="store_true", help="only redraw security.png from the security.json in --out")
    args = ap.parse_args(argv)
    out = Path(args.out)
    if args.replot:
        plot(json.loads((out / "security.json").read_text())["rows"], out / "security.png")
        return 0
    out.mkdir(parents=True, exist_ok=True)
    console = Console()
    rows, runs = [], []
    for i, n in enumerate(args.sizes):
        for cfg in args.configs:
            order = MODES if i % 2 == 0 else MODES[::-1]  # alternate who runs first
            got = {mode: measure(n, cfg, mode, args, console) for mode in order}
            runs += list(got.values())
            rows.append(side_by_side(got["off"], got["mtls"]))
            console.print(rows[-1])
    record = {"args": vars(args), "cores": psutil.cpu_count(), "target_pct": TARGET_OVERHEAD_PCT, "rows": rows, "runs": runs,
              "when": time.time()}
    write_results(out, "security", record, rows)
    plot(rows, out / "security.png")
    console.print(f"wrote {out / 'security'}.json/.csv/.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
