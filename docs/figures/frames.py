"""Draws docs/frames.png: the swarm's ENU frame beside each FCU's NED frame (docs/gcs.md, "Frames").

    python docs/figures/frames.py      # writes docs/frames.png
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.patches import FancyArrowPatch  # noqa: E402

OUT = Path(__file__).resolve().parents[1] / "frames.png"
ORIGIN = (0.0, 0.0)
SPAWNS = {1: (-26.0, -25.0), 2: (6.0, -25.0)}  # swarm frame x east, y north (m)
TARGET = (20.0, 10.0, 15.0)  # x east, y north, z up from the origin (m)
ALT0 = 446.0  # the origin's altitude AMSL (m), as in scenarios/coverage.yaml
SWARM, FCU, GEO = "#1f77b4", "#d62728", "#2ca02c"


def arrow(ax, a, b, color, lw=1.6, style="-|>", ls="-"):  # noqa: ANN001, ANN201
    ax.add_patch(FancyArrowPatch(a, b, arrowstyle=style, mutation_scale=12, color=color, lw=lw, linestyle=ls))


def main() -> None:
    fig, (ax, side) = plt.subplots(1, 2, figsize=(12, 6.4), gridspec_kw={"width_ratios": [2.3, 1]})
    tx, ty, tz = TARGET
    # the swarm frame: ENU from the scenario's origin
    ax.plot(*ORIGIN, "o", color=SWARM, ms=8)
    arrow(ax, ORIGIN, (9, 0), SWARM, 2.2)
    arrow(ax, ORIGIN, (0, 9), SWARM, 2.2)
    ax.text(9.5, -1.2, "x (east)", color=SWARM, fontsize=9)
    ax.text(0.8, 9.3, "y (north)", color=SWARM, fontsize=9)
    ax.text(-3, 2.2, "swarm origin\n(scenario origin)", color=SWARM, fontsize=9, ha="right")
    # each FCU's frame: NED from where that UAV spawned
    for uav, (sx, sy) in SPAWNS.items():
        ax.plot(sx, sy, "s", color=FCU, ms=7)
        arrow(ax, (sx, sy), (sx, sy + 7), FCU)
        arrow(ax, (sx, sy), (sx + 7, sy), FCU)
        ax.text(sx + 0.6, sy + 7.3, "N", color=FCU, fontsize=9)
        ax.text(sx + 7.3, sy - 0.4, "E", color=FCU, fontsize=9)
        label = f"UAV {uav} spawned here:\nits FCU's local origin\n(D points down)"
        ax.text(sx + 3, sy - 3.0, label, color=FCU, fontsize=8, ha="center", va="top")
    # one target, in the three ways to name it
    ax.plot(tx, ty, "*", color="black", ms=16)
    arrow(ax, ORIGIN, (tx, ty), SWARM, 1.4, ls="--")
    sx, sy = SPAWNS[2]
    arrow(ax, (sx, sy), (tx, ty), FCU, 1.4, ls="--")
    n, e = ty - sy, tx - sx
    ax.text(-44, 29, f"swarm ENU: x={tx:g}, y={ty:g}, z={tz:g}\n  mrswarm gcs goto {tx:g} {ty:g} {tz:g}",
            color=SWARM, fontsize=9, va="top")
    ned = f"UAV 2's NED: north={n:g}, east={e:g}, down={-tz:g}\n  MAVSDK offboard set_position_ned({n:g}, {e:g}, {-tz:g}, yaw)"
    ax.text(12, -6, ned, color=FCU, fontsize=9, va="top")
    amsl = ALT0 + tz
    geo = (f"geodetic: lat, lon, {amsl:g} m AMSL\n  gcs goto --geo LAT,LON,{amsl:g}\n"
           f"  MAVSDK goto_location(lat, lon, {amsl:g}, yaw)")
    ax.text(-44, 19, geo, color=GEO, fontsize=9, va="top")
    ax.set(xlim=(-46, 66), ylim=(-42, 32), xlabel="east of the swarm origin (m)", ylabel="north of the swarm origin (m)",
           title="Seen from above: one point, three frames")
    ax.set_aspect("equal")
    ax.grid(alpha=0.25)
    # heights: swarm z up from the origin's altitude; NED down from the spawn (on the ground); AMSL
    side.axhline(0, color="0.4", lw=1)
    side.text(0.02, -1.6, f"ground = origin altitude ({ALT0:g} m AMSL)\nevery UAV spawns on it", fontsize=8, color="0.3")
    side.plot([0.5], [tz], "*", color="black", ms=16)
    arrow(side, (0.15, 0), (0.15, tz), SWARM, 1.6)
    side.text(0.18, tz / 2, f"swarm z\n= +{tz:g} (up)", color=SWARM, fontsize=9, va="center")
    arrow(side, (0.7, 0), (0.7, tz), FCU, 1.6)
    side.text(0.73, tz / 2, f"NED down\n= {-tz:g}", color=FCU, fontsize=9, va="center")
    side.text(0.05, tz + 1.2, f"altitude {ALT0 + tz:g} m AMSL (geodetic)", color=GEO, fontsize=9)
    side.set(xlim=(0, 1.1), ylim=(-4, tz + 5), ylabel="height above the origin (m)", title="Heights")
    side.set_xticks([])
    side.grid(alpha=0.25, axis="y")
    fig.suptitle("Frames: the swarm's ENU (mrswarm gcs, poses) and each FCU's NED (MAVSDK offboard, LOCAL_POSITION_NED)")
    fig.tight_layout()
    fig.savefig(OUT, dpi=110)
    print(OUT)


if __name__ == "__main__":
    main()
