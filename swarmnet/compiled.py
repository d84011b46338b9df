"""Moved to :mod:`groundfloor.compiled`; this name stays only until uav_stack/fcu/ imports it from there."""

from groundfloor.compiled import compiled_module

__all__ = ["compiled_module"]
