"""A run's results: from the files of a run folder to summary.json, its figures and the printed table.

analysis.py reads the UAVs' files once and computes the numbers (a :class:`~mrswarm.records.summary.RunSummary`)
and the series behind them (:class:`~mrswarm.results.run_data.RunData`); each report fills one part of the
summary from what analysis hands it (fault_report.py, netem_report.py, world_report.py, incidents.py,
degraded.py; coverage.py is the coverage rule, shared with the runner's live estimate); plots.py and
world_plots.py draw RunData and compute nothing; summary_table.py prints the summary. summarise.py ties them
together for the runner and ``mrswarm results``. Reads only the run folder (and the scenario saved in it):
never imports mrswarm/run/ or mrswarm/cli/.
"""
