"""Does compiling the UAV's Python make a lone virtual UAV cheaper? Pure Python against Cython or mypyc.

A lone virtual UAV spends over half of its CPU in the CPython interpreter (docs/performance.md),
so the obvious question is whether compiled code would run the same work for less. This copies
the checkout into a temporary folder, compiles the modules on a UAV's per-tick path there,
then flies a lone UAV (``benchmarks/scale.py --sizes 1 --configs CONFIG``) from the checkout and
from the compiled copy, alternated round by round, and compares the CPU of the UAV process (% of
one core, the scale benchmark's own meter over its window). Two compilers:

* ``--compiler cython``: Cython on unchanged sources (the ``.py`` files removed so that only
  the compiled ones can load);
* ``--compiler mypyc``: mypy's compiler, which turns the type-annotated classes into native
  ones (:data:`MYPYC_MODULES`; the modules defining msgspec structs and pymavlink subclasses
  stay Python), after three edits mypyc needs and Python does not (:data:`MYPYC_EDITS`).
  A compiled module loads before its ``.py``, which is left in place.

    pip install cython   # and a C compiler with Python's headers (apt: gcc python3-dev)
    python benchmarks/compiled_uav.py --rounds 3 --out benchmarks/results
    # -> benchmarks/results/compiled_uav.{json,csv,png}; about 15 minutes on 2 cores
    python benchmarks/compiled_uav.py --compiler mypyc --config default --rounds 4 --out benchmarks/results
    # -> benchmarks/results/compiled_uav_mypyc.*; mypyc comes with mypy (the test extra)

pymavlink's generated dialect, the largest pure-Python piece on the path, is not compiled here:
its 1.7 MB of Python become 36 MB of C that take gcc over half an hour.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.output import write_results  # noqa: E402

# The modules a virtual UAV runs every tick or every second: its FCU, its agent and its
# behaviours, the swarm node and its receive path, the discovery proxy.
HOT_MODULES = [
    *(f"uav_stack/fcu/{m}.py" for m in ("fcu", "vehicle", "telemetry", "dynamics", "clock", "link", "handlers",
                                        "offboard", "modes", "mission", "commands", "stats")),
    *(f"uav_stack/{m}.py" for m in ("agent", "runtime", "fcu_link", "fcu_udp", "udp", "recorder", "pose_age", "rtf",
                                    "geo", "failsafe", "overrides", "sensors", "autopilot", "mavlink_router")),
    *(f"uav_stack/behaviours/{m}.py" for m in ("coverage", "avoidance", "base", "lp", "zones")),
    *(f"swarmnet/{m}.py" for m in ("node", "receive", "messages", "stats", "neighbours", "feed", "interest",
                                   "keyspace")),
    "swarmnet/netem/shim.py",
    "groundfloor/histogram.py",
    "discovery/proxy.py",
    "discovery/wire.py",
]
PACKAGES = ["groundfloor", "swarmnet", "discovery", "uav_stack", "world", "deploy", "mrswarm", "benchmarks", "scenarios"]

# mypyc: the per-tick modules it compiles as they are (failsafe.py and swarmnet/messages.py
# define msgspec structs whose annotations the config loader reads; mavcodec.py subclasses
# pymavlink's untyped MAVLink class).
MYPYC_MODULES = [
    *(f"uav_stack/fcu/{m}.py" for m in ("fcu", "vehicle", "telemetry", "clock", "link", "handlers", "offboard", "stats")),
    *(f"uav_stack/{m}.py" for m in ("agent", "fcu_link", "fcu_udp", "udp", "recorder", "rtf", "geo", "mavlink_router")),
    *(f"swarmnet/{m}.py" for m in ("node", "receive", "neighbours")),
]
# (file, text, replacement): what mypyc rejects and Python does not mind
MYPYC_EDITS = [
    # an exception class that subclasses OSError cannot be a native class
    ("uav_stack/fcu_link.py", "class LinkOpenError(OSError, MrswarmError):",
     "from mypy_extensions import mypyc_attr\n\n\n@mypyc_attr(native_class=False)\nclass LinkOpenError(OSError, MrswarmError):"),
    # a native class has no __dict__
    ("uav_stack/mavlink_router.py", "return dict(self.__dict__)", "return dict(__import__('dataclasses').asdict(self))"),
    # an attribute named _thread becomes a C field named __thread, a keyword of gcc
    ("swarmnet/receive.py", "_thread", "_worker_thread"),
]


def compiled_copy(dest: Path, jobs: int) -> float:
    """Copy the checkout's packages to ``dest`` and compile HOT_MODULES there; returns the build's seconds."""
    for pkg in PACKAGES:
        shutil.copytree(ROOT / pkg, dest / pkg, ignore=shutil.ignore_patterns("__pycache__", "results"))
    t0 = time.monotonic()
    # annotation_typing=False: Cython would otherwise enforce the annotations strictly (a str
    # enum member is not a ``str`` to it), which changes what the code accepts
    res = subprocess.run([sys.executable, "-m", "Cython.Build.Cythonize", "-i", "-3", "-j", str(jobs), "-q",
                          "-X", "annotation_typing=False", *HOT_MODULES], cwd=dest, capture_output=True, text=True,
                         timeout=3600)
    if res.returncode != 0:
        raise SystemExit(f"cythonize failed (is Cython installed, with gcc and Python's headers?):\n{res.stderr[-3000:]}")
    for src in built(dest, HOT_MODULES, "cythonize"):
        src.unlink()  # only the compiled module can load now
        src.with_suffix(".c").unlink(missing_ok=True)
    return time.monotonic() - t0


def built(dest: Path, modules: list[str], compiler: str) -> list[Path]:
    """The sources of ``modules`` under ``dest``, each checked to have its compiled extension beside it."""
    sources = [dest / mod for mod in modules]
    for src in sources:
        if not list(src.parent.glob(src.stem + ".*.so")):
            raise SystemExit(f"{compiler} built no extension for {src.relative_to(dest)}")
    return sources


def mypyc_copy(dest: Path) -> float:
    """Copy the checkout's packages to ``dest``, edit them (:data:`MYPYC_EDITS`) and compile
    :data:`MYPYC_MODULES` there with mypyc; returns the build's seconds."""
    for pkg in PACKAGES:
        shutil.copytree(ROOT / pkg, dest / pkg, ignore=shutil.ignore_patterns("__pycache__", "results"))
    shutil.copy(ROOT / "pyproject.toml", dest / "pyproject.toml")  # mypy's settings
    for rel, old, new in MYPYC_EDITS:
        path = dest / rel
        text = path.read_text()
        if old not in text:
            raise SystemExit(f"{rel}: {old!r} is gone; update MYPYC_EDITS")
        path.write_text(text.replace(old, new))
    t0 = time.monotonic()
    build = ("import sys\nfrom mypyc.build import mypycify\nfrom setuptools import setup\n"
             f"setup(name='uav-mypyc', ext_modules=mypycify({MYPYC_MODULES!r}, opt_level='3'), "
             "script_args=['build_ext', '--inplace'])\n")
    res = subprocess.run([sys.executable, "-c", build], cwd=dest, capture_output=True, text=True, timeout=3600)
    if res.returncode != 0:
        raise SystemExit(f"mypyc failed (is mypy installed, with gcc and Python's headers?):\n{res.stdout[-3000:]}")
    built(dest, MYPYC_MODULES, "mypyc")
    return time.monotonic() - t0


def fly_lone_uav(tree: Path, out: Path, window: float, config: str) -> dict[str, Any]:
    """One lone-UAV run of the scale benchmark from ``tree``; its row (CPU, RSS, RTF)."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    res = subprocess.run([sys.executable, "benchmarks/scale.py", "--sizes", "1", "--configs", config,
                          "--window", str(window), "--out", str(out)], cwd=tree, env=env, capture_output=True,
                         text=True, timeout=300 + window)
    rows = json.loads((out / "scale.json").read_text())["rows"] if (out / "scale.json").exists() else []
    if res.returncode != 0 or not rows or rows[0].get("cpu_pct_median") is None:
        raise SystemExit(f"the lone UAV from {tree} did not fly:\n{res.stdout[-2000:]}\n{res.stderr[-2000:]}")
    return rows[0]


def plot(rows: list[dict[str, Any]], compiler: str, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    variants = ["python", compiler]
    fig, ax = plt.subplots(figsize=(5, 3.5))
    for i, v in enumerate(variants):
        vals = [r["cpu_pct"] for r in rows if r["variant"] == v]
        ax.bar(i, statistics.median(vals), color="tab:blue" if v == "python" else "tab:orange", alpha=0.6)
        ax.plot([i] * len(vals), vals, "k.", ms=8)
    ax.set_xticks(range(len(variants)), ["pure Python", f"{'Cython' if compiler == 'cython' else 'mypyc'}-compiled"])
    ax.set_ylabel("lone UAV process CPU, % of a core")
    ax.set_title("A lone virtual UAV: median (bar) and each run (dots)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3, help="rounds of one run per variant, order alternated")
    ap.add_argument("--window", type=float, default=40.0, help="s of each run's CPU measurement")
    ap.add_argument("--jobs", type=int, default=2, help="parallel compiler jobs (Cython)")
    ap.add_argument("--compiler", choices=["cython", "mypyc"], default="cython")
    ap.add_argument("--config", default="discovery-direct", help="the scale benchmark's configuration flown")
    ap.add_argument("--out", type=Path, default=None, help="folder for compiled_uav.{json,csv,png} (default: print only)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="mrswarm-compiled-") as tmp:
        copy = Path(tmp) / "tree"
        compiler = args.compiler
        modules = HOT_MODULES if compiler == "cython" else MYPYC_MODULES
        build_s = compiled_copy(copy, args.jobs) if compiler == "cython" else mypyc_copy(copy)
        print(f"compiled {len(modules)} modules with {compiler} in {build_s:.0f} s")
        trees = {"python": ROOT, compiler: copy}
        rows: list[dict[str, Any]] = []
        for r in range(args.rounds):
            for variant in ("python", compiler) if r % 2 == 0 else (compiler, "python"):
                row = fly_lone_uav(trees[variant], Path(tmp) / f"{variant}{r}", args.window, args.config)
                rows.append({"round": r, "variant": variant, "cpu_pct": row["cpu_pct_median"],
                             "rss_mb": row["rss_mb_median"], "rtf": row["rtf_mean"]})
                print(f"round {r} {variant:7s}: CPU {row['cpu_pct_median']:.2f} % of a core, "
                      f"RSS {row['rss_mb_median']:.1f} MB, RTF {row['rtf_mean']:.3f}", flush=True)
    med = {v: statistics.median(r["cpu_pct"] for r in rows if r["variant"] == v) for v in trees}
    print(f"median CPU: pure Python {med['python']:.2f} %, {compiler} {med[compiler]:.2f} % "
          f"(ratio {med[compiler] / med['python']:.2f})")
    if args.out is not None:
        name = "compiled_uav" if compiler == "cython" else "compiled_uav_mypyc"
        record = {"compiler": compiler, "config": args.config, "build_s": round(build_s, 1), "modules": modules,
                  "edits": MYPYC_EDITS if compiler == "mypyc" else [], "median_cpu_pct": med, "rows": rows}
        write_results(args.out, name, record, rows)
        plot(rows, compiler, args.out / f"{name}.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
