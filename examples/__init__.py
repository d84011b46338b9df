"""Swarm algorithms from the literature written on mrswarm's behaviour SDK (docs/sdk.md)."""
