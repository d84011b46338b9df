"""The shape of a socket address, named once."""

from __future__ import annotations

from typing import TypeAlias

Addr: TypeAlias = tuple[str, int]
"""An IPv4 or IPv6 host and a port, as ``socket`` takes and gives them (``("127.0.0.1", 7447)``)."""
