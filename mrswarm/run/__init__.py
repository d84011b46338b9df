"""Running an experiment: ``mrswarm run`` from a loaded scenario to a stopped swarm and its summary.

The runner (experiment.py) drives a runtime (runtime.py, deploy/), supervises the processes (supervisor.py,
stalls.py), injects the fault schedule (chaos.py), shows the live status (live.py, display.py) and hands the
run folder to mrswarm/results/ when it stops. Imports mrswarm/results/, mrswarm/records/ and mrswarm/scenario/,
never mrswarm/cli/.
"""
