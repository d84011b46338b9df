"""Burnt area and time until the fire is out, against the number of firefighting UAVs (docs/world.md).

Runs ``scenarios/wildfire.yaml`` (the same fire, the same hub, the same no-fly zone) once per
swarm size with ``mrswarm run``, each UAV its own process, and collects from every run's
summary: the burnt area, the cells put out, the litres sprayed, and when the last burning cell
went out (by the UAVs, or because the forest had burnt down), plus the burnt area over time.

    python benchmarks/wildfire_table.py --sizes 1 2 4 8 12 20 --duration 150 --out benchmarks/results

writes ``wildfire_table.json``, ``wildfire_table.md`` (the table of docs/world.md) and
``wildfire_table.png``. One run per size: the fire model is deterministic, the flights are not
(process timing), so sizes next to each other can swap places; repeat with ``--repeats``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]


def one_run(n: int, duration: float, work: Path, seed: int) -> dict[str, Any]:
    out = work / f"n{n}-s{seed}"
    cmd = [sys.executable, "-m", "mrswarm", "run", str(ROOT / "scenarios" / "wildfire.yaml"), "--no-live", "--out", str(out),
           "--set", f"fleet.count={n}", "--set", f"duration={duration}", "--set", f"seed={seed}"]
    t = time.monotonic()
    res = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=duration + 600)
    run_dir = next((d for d in out.iterdir() if d.is_dir()), None) if out.exists() else None
    if run_dir is None or not (run_dir / "summary.json").exists():
        return {"n": n, "seed": seed, "error": f"exit {res.returncode}: {res.stdout[-500:]}{res.stderr[-500:]}"}
    s = json.loads((run_dir / "summary.json").read_text())
    fire = (s.get("world") or {}).get("fire") or {}
    return {
        "n": n, "seed": seed, "run_dir": str(run_dir), "wall_s": round(time.monotonic() - t, 1),
        "burnt_area_m2": fire.get("burnt_area_m2"), "cells_ignited": fire.get("cells_ignited"),
        "cells_extinguished": fire.get("cells_extinguished"), "cells_burning_at_end": fire.get("cells_burning_at_end"),
        "fire_out_at_s": fire.get("extinguished_at_s"), "sprayed_l": fire.get("sprayed_l"),
        "area_curve": fire.get("area_curve"), "zone_entries": ((s.get("world") or {}).get("zones") or {}).get("entries"),
        "collisions": (s.get("separation") or {}).get("collisions"), "rtf_min": (s.get("rtf") or {}).get("min"),
        "aborted": s.get("aborted"),
    }


BURNT_DOWN = 0.9  # of the burnable cells: a fire that got this far went out because nothing was left


def table(rows: list[dict[str, Any]], cells_total: int) -> str:
    lines = ["| UAVs | burnt area (m²) | burnt share | cells put out | sprayed (l) | fire out at (s) | how it ended |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['n']} | run failed: {r['error'][:60]} | | | | | |")
            continue
        out = r["fire_out_at_s"]
        put_out = r["cells_extinguished"] or 0
        if out is None:
            how = f"still burning ({r['cells_burning_at_end']} cells)"
        elif r["cells_ignited"] >= BURNT_DOWN * cells_total:
            how = "the forest burnt down"
        else:
            how = "put out by the swarm"
        lines.append(f"| {r['n']} | {r['burnt_area_m2']:.0f} | {100 * r['cells_ignited'] / cells_total:.0f} % | {put_out} | "
                     f"{r['sprayed_l']:.0f} | {'-' if out is None else f'{out:.0f}'} | {how} |")
    return "\n".join(lines)


def plot(rows: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 5))
    for r in rows:
        c = r.get("area_curve") or []
        if c:
            ax.plot([p[0] for p in c], [p[1] for p in c], lw=1.5, label=f"{r['n']} UAV{'s' if r['n'] > 1 else ''}")
    ax.set_xlabel("time since the fire started (s)")
    ax.set_ylabel("burnt area (m²)")
    ax.set_title("wildfire.yaml: burnt area over time against swarm size")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[1, 2, 4, 8, 12, 20])
    ap.add_argument("--duration", type=float, default=150.0, help="mission seconds per run")
    ap.add_argument("--repeats", type=int, default=1, help="runs per size (seeds 5, 6, ...)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    ap.add_argument("--redraw", action="store_true", help="only redraw the table and figure from the JSON in --out")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    out = Path(args.out)
    if args.redraw:
        meta = json.loads((out / "wildfire_table.json").read_text())
        md = table(meta["runs"], meta["burnable_cells"])
        (out / "wildfire_table.md").write_text(md + "\n")
        plot(meta["runs"], out / "wildfire_table.png")
        print(md)
        return 0
    from mrswarm.scenario import load_scenario
    from world.fire import FireGrid

    scn = load_scenario(ROOT / "scenarios" / "wildfire.yaml")
    assert scn.world is not None and scn.world.fire is not None
    grid = FireGrid(scn.world.fire, scn.world.wind)
    burnable = int((grid.fuel > 0).sum())
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    with tempfile.TemporaryDirectory(prefix="wildfire-table-") as work:
        for n in args.sizes:
            for k in range(args.repeats):
                r = one_run(n, args.duration, Path(work), seed=5 + k)
                print(json.dumps({k2: v for k2, v in r.items() if k2 != "area_curve"}), flush=True)
                rows.append(r)
    meta = {"scenario": "scenarios/wildfire.yaml", "duration_s": args.duration, "burnable_cells": burnable,
            "cell_m": scn.world.fire.cell_m, "measured": time.strftime("%Y-%m-%d %H:%M"), "runs": rows}
    (out / "wildfire_table.json").write_text(json.dumps(meta, indent=1))
    md = table(rows, burnable)
    (out / "wildfire_table.md").write_text(md + "\n")
    plot(rows, out / "wildfire_table.png")
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
