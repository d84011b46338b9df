"""Source localisation error over time in ``scenarios/plume.yaml`` (docs/world.md).

Runs the plume scenario with ``mrswarm run`` (``--repeats`` times, seeds 3, 4, ...) and
collects from each run's summary the error of the UAVs' source estimates against the true
source, once a second: the median over the UAVs and the best UAV.

    python benchmarks/plume_localisation.py --repeats 3 --out benchmarks/results

writes ``plume_localisation.json`` and ``plume_localisation.png``; ``--set`` passes scenario
overrides (``--set mission.plume.strategy=stop`` for the e-puck stop rule).
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


def one_run(seed: int, sets: list[str], work: Path) -> dict[str, Any]:
    out = work / f"s{seed}"
    cmd = [sys.executable, "-m", "mrswarm", "run", str(ROOT / "scenarios" / "plume.yaml"), "--no-live", "--out", str(out),
           "--set", f"seed={seed}"] + [a for s in sets for a in ("--set", s)]
    res = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=900)
    run_dir = next((d for d in out.iterdir() if d.is_dir()), None) if out.exists() else None
    if run_dir is None or not (run_dir / "summary.json").exists():
        return {"seed": seed, "error": f"exit {res.returncode}: {res.stdout[-500:]}{res.stderr[-500:]}"}
    s = json.loads((run_dir / "summary.json").read_text())
    p = (s.get("world") or {}).get("plume") or {}
    return {"seed": seed, **{k: v for k, v in p.items()}, "collisions": (s.get("separation") or {}).get("collisions"),
            "rtf_min": (s.get("rtf") or {}).get("min")}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="plume-") as work:
        runs = [one_run(3 + k, args.set, Path(work)) for k in range(args.repeats)]
    for r in runs:
        print(json.dumps({k: v for k, v in r.items() if k != "error_curve"}), flush=True)
    (out / "plume_localisation.json").write_text(json.dumps({"measured": time.strftime("%Y-%m-%d %H:%M"), "sets": args.set,
                                                             "runs": runs}, indent=1))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.5))
    for r in runs:
        c = r.get("error_curve") or []
        line = ax.plot([p[0] for p in c], [p[1] for p in c], lw=1.8, label=f"seed {r['seed']}: median over UAVs")
        ax.plot([p[0] for p in c], [p[2] for p in c], lw=0.8, ls=":", color=line[0].get_color())
    ax.axvline(60.0, color="tab:purple", ls="--", lw=1, label="wind turns 100 deg")
    ax.set_xlabel("time since mission start (s)")
    ax.set_ylabel("source localisation error (m)")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("plume.yaml: localisation error (dotted: best UAV)")
    fig.tight_layout()
    fig.savefig(out / "plume_localisation.png", dpi=110)
    return 0


if __name__ == "__main__":
    sys.exit(main())
