"""The typed records of a run folder: ``run.json`` (what the runner saw) and ``summary.json`` (what the analysis found).

Every room reads or writes them: the runner writes run.json, mrswarm/results/ writes summary.json, the recorder
rebuilds run.json from a recording, sweeps read summaries. So they stand below all of those and import none.
"""
