"""The FCU link's MAVLink framing per message, in-process: pymavlink against the compiled pass.

Packs and parses the messages a virtual UAV's FCU link carries every tick (the FCU's
GLOBAL_POSITION_INT, ATTITUDE and LOCAL_POSITION_NED, the agent's
SET_POSITION_TARGET_LOCAL_NED) as one datagram of the four, the way the link does it:
``uav_stack.mavcodec.pack`` and ``mavcodec.MAVLink.parse_datagram`` (the compiled pass,
``uav_stack._mavcodec``) against pymavlink's ``msg.pack(mav)`` and ``parse_buffer``, the two
alternated in each of ``--rounds`` rounds, and reports the median CPU time per message (µs).

The numbers are warm (the same messages again and again, caches hot): a UAV that wakes ten
times a second pays a few times more per message; ``scale.py`` and ``commits.py`` measure that.

    python benchmarks/mavlink_codec.py --rounds 5 --out benchmarks/results
    # -> benchmarks/results/mavlink_codec.{json,csv,png}; about 20 seconds
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.output import write_results  # noqa: E402
from uav_stack import mavcodec  # noqa: E402
from uav_stack.mav import mavlink as M  # noqa: E402


def _messages() -> list[Any]:
    return [
        M.MAVLink_global_position_int_message(123456, 473977420, 85455940, 520000, 32000, 512, -230, 12, 27000),
        M.MAVLink_attitude_message(123456, 0.02, -0.01, 1.57, 0.001, 0.002, 0.01),
        M.MAVLink_local_position_ned_message(123456, 10.5, -3.25, -32.0, 5.1, -2.3, 0.12),
        M.MAVLink_set_position_target_local_ned_message(123456, 1, 1, M.MAV_FRAME_LOCAL_NED, 0b110111000111,
                                                        0, 0, 0, 5.1, -2.3, 0.0, 0, 0, 0, 0, 0),
    ]


def _per_message_us(fn: Callable[[], object], messages: int, seconds: float) -> float:
    """CPU µs per message of ``fn`` (which handles ``messages`` messages per call), over about ``seconds``."""
    calls, t0 = 0, time.process_time()
    while time.process_time() - t0 < seconds:
        for _ in range(200):
            fn()
        calls += 200
    return (time.process_time() - t0) / (calls * messages) * 1e6


def measure(rounds: int, seconds: float) -> list[dict[str, Any]]:
    if mavcodec.MAVCODEC != "compiled":
        raise SystemExit("uav_stack._mavcodec is not built (pip install -e . with gcc and Python's headers)")
    msgs = _messages()
    mav = M.MAVLink(None, 1, 1)
    datagram = b"".join(m.pack(mav) for m in msgs)
    ours, theirs = mavcodec.MAVLink(None), M.MAVLink(None)

    def reference_parse() -> object:
        theirs.buf, theirs.buf_index = bytearray(), 0
        return theirs.parse_buffer(datagram)

    cases: dict[tuple[str, str], Callable[[], object]] = {
        ("pack", "pymavlink"): lambda: [m.pack(mav) for m in msgs],
        ("pack", "compiled"): lambda: [mavcodec.pack(m, mav) for m in msgs],
        ("parse", "pymavlink"): reference_parse,
        ("parse", "compiled"): lambda: ours.parse_datagram(datagram),
    }
    rows: list[dict[str, Any]] = []
    for r in range(rounds):
        for (op, codec), fn in cases.items():
            rows.append({"round": r, "op": op, "codec": codec,
                         "us_per_message": round(_per_message_us(fn, len(msgs), seconds), 3)})
    return rows


def summarise(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    out = []
    for op in ("pack", "parse"):
        med = {c: statistics.median(r["us_per_message"] for r in rows if r["op"] == op and r["codec"] == c)
               for c in ("pymavlink", "compiled")}
        out.append({"op": op, "pymavlink_us": round(med["pymavlink"], 3), "compiled_us": round(med["compiled"], 3),
                    "ratio": round(med["pymavlink"] / med["compiled"], 2)})
    return out


def plot(summary: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 3.2))
    x = range(len(summary))
    ax.bar([i - 0.2 for i in x], [s["pymavlink_us"] for s in summary], 0.4, label="pymavlink")
    ax.bar([i + 0.2 for i in x], [s["compiled_us"] for s in summary], 0.4, label="compiled pass")
    ax.set_xticks(list(x), [s["op"] for s in summary])
    ax.set_ylabel("CPU µs per message (warm, median)")
    ax.set_title("FCU link framing per message")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--seconds", type=float, default=1.0, help="CPU seconds per case and round")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    ap.add_argument("--tag", default="mavlink_codec")
    args = ap.parse_args(argv)
    rows = measure(args.rounds, args.seconds)
    summary = summarise(rows)
    write_results(args.out, args.tag, {"args": {"rounds": args.rounds, "seconds": args.seconds},
                                       "summary": summary, "rows": rows}, summary)
    plot(summary, args.out / f"{args.tag}.png")
    for s in summary:
        print(f"{s['op']:6s} pymavlink {s['pymavlink_us']:6.2f} µs  compiled {s['compiled_us']:6.2f} µs  "
              f"x{s['ratio']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
