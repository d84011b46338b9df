"""Where a virtual UAV's loop spends its CPU, by Python function, without a profiler's own cost.

cProfile and py-spy mislead on a UAV: cProfile adds about a microsecond to every call, so
code with many small calls (pose decoding, pymavlink) looks several times dearer than it is,
and py-spy's idle detection counts waiting threads as busy. This uses Linux ``perf`` with
CPython's perf trampolines (Python >= 3.12, ``PYTHONPERFSUPPORT=1``): each sample of the UAV's
main thread (its loop: virtual FCU, agent, records) is charged to the innermost Python function
on its stack, C code and system calls included (a ``sendto`` to the function that called it).

It flies ``benchmarks/scale.py`` (``--n`` UAVs, ``--config``) with the given interpreter, samples
one UAV's main thread for ``--seconds`` once the mission runs, and writes the shares by function
and by file, with a plot::

    apt-get install linux-perf                       # Debian; perf must run as root
    python3.12 -m venv /tmp/v312 && /tmp/v312/bin/pip install -e .
    python benchmarks/uav_profile.py --python /tmp/v312/bin/python --n 50 --out benchmarks/results
    # -> benchmarks/results/uav_profile_n50.{json,csv,png}; about 3 minutes

The interpreter must be 3.12 or newer (3.11 has no perf trampolines). Shares are of the
samples of that one thread; its total CPU is what ``scale.py`` reports for the whole process,
less Zenoh's and the pose inlet's threads.
"""

from __future__ import annotations

import argparse
import collections
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.output import plot_shares, write_results  # noqa: E402

_PY_FRAME = re.compile(r"py::([^:\s]+):(\S+)")
WARMUP_S = 30.0  # s from the launch to the first sample: processes up, takeoff, mission started


def innermost_python(script: str) -> tuple[collections.Counter[tuple[str, str]], int]:
    """Samples per (function, file) of ``perf script -F ip,sym`` output, each charged to the
    innermost Python frame of its stack; samples with none are under ("<no Python frame>", "")."""
    counts: collections.Counter[tuple[str, str]] = collections.Counter()
    total = 0
    for block in script.split("\n\n"):
        if not block.strip():
            continue
        total += 1
        m = _PY_FRAME.search(block)  # stacks are printed innermost first
        counts[(m.group(1), _short(m.group(2))) if m else ("<no Python frame>", "")] += 1
    return counts, total


def _short(path: str) -> str:
    """A file as a reader knows it: the project's relative path, or a library's from its package on."""
    if path.startswith(str(ROOT) + "/"):
        return path[len(str(ROOT)) + 1:]
    return re.sub(r"^.*/(site-packages|lib/python3\.\d+)/", "", path)  # a library, or the standard library


def find_uav(uav: int, deadline: float) -> int:
    """The pid of the virtual UAV process ``uav`` (its config file names it), waiting until ``deadline``."""
    pattern = f"uav_stack.virtual_uav --config .*/uav{uav}.json"
    while time.monotonic() < deadline:
        out = subprocess.run(["pgrep", "-f", pattern], capture_output=True, text=True).stdout.split()
        if out:
            return int(out[0])
        time.sleep(0.5)
    raise SystemExit(f"no process of UAV {uav} appeared")


def profile(args: argparse.Namespace, work: Path) -> tuple[collections.Counter[tuple[str, str]], int]:
    env = dict(os.environ, PYTHONPERFSUPPORT="1")
    window = args.seconds + WARMUP_S
    scale = subprocess.Popen([args.python, str(ROOT / "benchmarks" / "scale.py"), "--sizes", str(args.n), "--configs",
                              args.config, "--window", str(window), "--out", str(work), "--tag", "run"],
                             cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        pid = find_uav(args.uav or (args.n + 1) // 2, time.monotonic() + 120)
        time.sleep(WARMUP_S)
        data = work / "uav.perf"
        subprocess.run(["perf", "record", "-q", "-F", str(args.freq), "--call-graph", "dwarf,32768", "-t", str(pid),
                        "-o", str(data), "--", "sleep", str(args.seconds)], check=True, timeout=args.seconds + 120)
        script = subprocess.run(["perf", "script", "-i", str(data), "-F", "ip,sym"], capture_output=True, text=True,
                                check=True, timeout=900).stdout
        return innermost_python(script)
    finally:
        try:
            os.killpg(scale.pid, signal.SIGTERM)
        except ProcessLookupError:
            pass
        scale.wait(60)


def plot(rows: list[dict[str, Any]], path: Path, title: str) -> None:
    top = rows[:25]
    plot_shares(path, [f"{r['function']} ({Path(r['file']).name})" for r in top], [r["share_pct"] for r in top],
                "% of the main thread's samples (innermost Python function)", title, height=7)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--python", default=sys.executable, help="interpreter >= 3.12 with the project installed")
    ap.add_argument("--n", type=int, default=50, help="virtual UAVs")
    ap.add_argument("--config", default="default", help="scale.py network configuration")
    ap.add_argument("--uav", type=int, default=0, help="the UAV to sample (default: the middle one)")
    ap.add_argument("--seconds", type=float, default=40.0, help="s of sampling")
    ap.add_argument("--freq", type=int, default=4999, help="samples a second while the thread runs")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    ap.add_argument("--tag", default=None, help="file names (default uav_profile_n<N>)")
    args = ap.parse_args(argv)
    version = subprocess.run([args.python, "-c", "import sys; print(sys.version_info >= (3, 12))"], capture_output=True,
                             text=True).stdout.strip()
    if version != "True":
        ap.error(f"--python {args.python}: needs Python >= 3.12 for perf trampolines")
    with tempfile.TemporaryDirectory(prefix="uav_profile_") as tmp:
        counts, total = profile(args, Path(tmp))
    if not total:
        raise SystemExit("perf recorded no sample of the UAV's main thread")
    by_file: collections.Counter[str] = collections.Counter()
    for (_, f), c in counts.items():
        by_file[f] += c
    rows = [{"function": fn, "file": f, "samples": c, "share_pct": round(100.0 * c / total, 2)}
            for (fn, f), c in counts.most_common()]
    files = [{"file": f, "samples": c, "share_pct": round(100.0 * c / total, 2)} for f, c in by_file.most_common()]
    tag = args.tag or f"uav_profile_n{args.n}"
    record = {"args": {k: str(v) for k, v in vars(args).items()}, "samples": total, "by_function": rows, "by_file": files}
    write_results(args.out, tag, record, rows)
    plot(rows, args.out / f"{tag}.png", f"a UAV of {args.n} ({args.config}): its main thread by innermost Python function, "
                                         f"{total} samples")
    for r in files[:15]:
        print(f"{r['share_pct']:6.2f} %  {r['file']}")
    print(f"wrote {args.out / tag}.json/.csv/.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
