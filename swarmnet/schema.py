"""Moved to :mod:`groundfloor.schema`; this name stays only until uav_stack/failsafe.py imports it from there."""

from groundfloor.schema import Config, ConfigError

__all__ = ["Config", "ConfigError"]
