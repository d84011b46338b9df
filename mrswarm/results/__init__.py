"""A run's results: from the files of a run folder to summary.json, its figures and the printed table.

analysis.py computes the numbers once (a :class:`~mrswarm.records.summary.RunSummary` and the arrays behind
it, :class:`~mrswarm.results.analysis.RunData`); the reports (fault_report.py, netem_report.py, world_report.py,
incidents.py, degraded.py) each fill one part of it; plots.py and world_plots.py draw from what analysis handed
them; summary_table.py prints the summary. summarise.py ties them together for the runner and ``mrswarm results``.
Reads only the run folder (and the scenario saved in it): never imports mrswarm/run/ or mrswarm/cli/.
"""
