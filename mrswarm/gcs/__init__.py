"""``mrswarm gcs``: the ground station for live telemetry and overrides (docs/gcs.md).

Built on :class:`swarmnet.observer.SwarmObserver`; every subcommand is a module here and
``mrswarm.gcs.cli.main`` dispatches to them.
"""
