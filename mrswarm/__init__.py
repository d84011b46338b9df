"""mrswarm: mixed-reality drone-swarm experiments over cellular edge networks."""

from swarmnet.version import __version__

__all__ = ["__version__"]
