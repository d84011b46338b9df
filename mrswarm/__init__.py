"""mrswarm: mixed-reality drone-swarm experiments over cellular edge networks."""

__version__ = "0.1.0"
