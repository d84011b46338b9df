"""Where every benchmark's figures go: a JSON record and a CSV table of the same rows.

One writer for all of ``benchmarks/``, so every result folder looks alike and no file is ever
left half written: each file is written beside its final name and then renamed over it, so an
interrupted run leaves the previous results whole.
"""

from __future__ import annotations

import csv
import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any


def _replace(path: Path, write: Callable[[IO[str]], object]) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "w", newline="") as f:
        write(f)
    os.replace(tmp, path)


def write_results(out: Path, name: str, record: Any, rows: list[dict[str, Any]],
                  fieldnames: list[str] | None = None) -> None:
    """Write ``out/<name>.json`` (``record``: the rows and what a reader needs to redo them,
    such as the arguments) and ``out/<name>.csv`` (one line per row of ``rows``).

    The CSV's columns are ``fieldnames``, or else every key any row has, in first-seen order
    (rows of different configurations may carry different keys).
    """
    out.mkdir(parents=True, exist_ok=True)
    _replace(out / f"{name}.json", lambda f: f.write(json.dumps(record, indent=2) + "\n"))
    cols = fieldnames if fieldnames is not None else list(dict.fromkeys(k for r in rows for k in r))

    def table(f: IO[str]) -> None:
        w = csv.DictWriter(f, fieldnames=cols)
        w.writeheader()
        w.writerows(rows)

    _replace(out / f"{name}.csv", table)


def plot_shares(path: Path, labels: list[str], values: list[float], xlabel: str, title: str, height: float = 5.5) -> None:
    """A horizontal bar chart of shares (the largest first, at the top), as the profiling
    benchmarks draw where the CPU goes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, height))
    ax.barh(labels[::-1], values[::-1], color="tab:blue")
    ax.set_xlabel(xlabel)
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
