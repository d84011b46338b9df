"""The campaign's report from its folder alone: ``runs.csv``, ``cells.csv``, the plots and a printed table.

The sweep refreshes the two tables after every run (a campaign stopped half-way has its tables)
and writes everything at its end; ``mrswarm sweep --report DIR`` does the same from the folder.
"""

from __future__ import annotations

from pathlib import Path

from rich.console import Console
from rich.table import Table as RichTable

from mrswarm.sweep.campaign import value_label
from mrswarm.sweep.table import Table, collect, metric, write_tables

PRINTED_METRICS = 4


def refresh_tables(campaign_dir: Path) -> Table:
    t = collect(campaign_dir)
    write_tables(campaign_dir, t)
    return t


def build_report(campaign_dir: Path, console: Console | None = None, metrics: list[str] | None = None) -> list[Path]:
    """Tables and plots of ``campaign_dir``; prints the cells' table on ``console``. Returns the files written."""
    from mrswarm.sweep.plots import write_plots

    t = collect(campaign_dir, metrics)
    paths = write_tables(campaign_dir, t)
    try:
        paths += write_plots(campaign_dir, t)
    except Exception as exc:  # a figure that fails to draw must not lose the tables
        if console is not None:
            console.print(f"[yellow]warning:[/] the plots failed: {exc!r}", highlight=False)
    if console is not None:
        print_cells(console, t)
    return paths


def fmt(v: float | None, scale: float = 1.0) -> str:
    """A value with three decimals below 10, two below 100, one below 1000, else none."""
    if v is None:
        return "-"
    x = v * scale
    digits = 3 if abs(x) < 10 else 2 if abs(x) < 100 else 1 if abs(x) < 1000 else 0
    return f"{x:,.{digits}f}"


def print_cells(console: Console, t: Table) -> None:
    """One row per cell: its runs and, for the first plotted metrics, mean [interval]."""
    if not t.cells:
        console.print("no complete run yet", highlight=False)
        return
    room = (console.width - sum(max(len(k), 6) + 3 for k in t.grid) - 8) // 18  # the value columns that fit unwrapped
    shown = t.plots[:max(1, min(PRINTED_METRICS, room))]
    table = RichTable(title=f"{t.name}: mean ± half-width of its {100 * t.level:g} % confidence interval",
                      title_justify="left", show_edge=False)
    for k in t.grid:
        table.add_column(k)
    table.add_column("runs", justify="right", no_wrap=True)
    for m in shown:
        table.add_column(metric(m).head, justify="right", no_wrap=True)
    for c in t.cells:
        runs = f"{c.ok}" + (f" +{c.failed} failed" if c.failed else "") + (f" +{c.pending} to fly" if c.pending else "")
        cols = []
        for m in shown:
            s = c.stats[m]
            sc = metric(m).scale
            text = fmt(s.mean, sc)
            if s.half_width is not None:
                text += f" ± {fmt(s.half_width, sc)}"
            if s.n < s.runs:
                text += f" ({s.n}/{s.runs})"
            cols.append(text)
        table.add_row(*(value_label(c.values.get(k)) for k in t.grid), runs, *cols)
    console.print(table)
