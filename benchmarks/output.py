"""Where every benchmark's figures go: a JSON record and a CSV table of the same rows.

One writer for all of ``benchmarks/``, so every result folder looks alike and no file is ever
left half written: each file is written beside its final name and then renamed over it, so an
interrupted run leaves the previous results whole.
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Any

from groundfloor.files import write_atomic


def write_results(out: Path, name: str, record: Any, rows: list[dict[str, Any]],
                  fieldnames: list[str] | None = None) -> None:
    """Write ``out/<name>.json`` (``record``: the rows and what a reader needs to redo them,
    such as the arguments) and ``out/<name>.csv`` (one line per row of ``rows``).

    The CSV's columns are ``fieldnames``, or else every key any row has, in first-seen order
    (rows of different configurations may carry different keys).
    """
    out.mkdir(parents=True, exist_ok=True)
    write_atomic(out / f"{name}.json", json.dumps(record, indent=2) + "\n")
    cols = fieldnames if fieldnames is not None else list(dict.fromkeys(k for r in rows for k in r))

    table = io.StringIO(newline="")
    w = csv.DictWriter(table, fieldnames=cols)
    w.writeheader()
    w.writerows(rows)
    write_atomic(out / f"{name}.csv", table.getvalue())


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
