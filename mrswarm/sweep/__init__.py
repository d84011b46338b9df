"""``mrswarm sweep``: a campaign of runs over a grid of scenario overrides and seeds (docs/campaigns.md).

* :mod:`mrswarm.sweep.campaign`: the campaign file (msgspec, errors naming the field), its cells and run slots;
* :mod:`mrswarm.sweep.slots`: a slot's folder on disk (its attempts, which one is complete);
* :mod:`mrswarm.sweep.capacity`: whether the machine has room for one more run beside those running;
* :mod:`mrswarm.sweep.launch`: one run as ``mrswarm run ... --out <slot>`` in a child process, its CPU time;
* :mod:`mrswarm.sweep.runner`: the schedule (resume, parallel runs, Ctrl-C);
* :mod:`mrswarm.sweep.progress`: the progress bar (or plain lines) with the time left;
* :mod:`mrswarm.sweep.stats`: means, medians and t-distribution confidence intervals (no scipy);
* :mod:`mrswarm.sweep.table`: every run's metrics into ``runs.csv``, per cell ``cells.csv``;
* :mod:`mrswarm.sweep.plots`: each metric against the swept parameter, with its interval;
* :mod:`mrswarm.sweep.cli`: the command.
"""
