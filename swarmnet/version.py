"""The software version, read once from the installed package's metadata.

It lives in the bottom layer so that every layer (the discovery beacons, the image tag of the
container runtime, ``mrswarm --version``) can name it without importing a layer above.
"""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("mrswarm")
except PackageNotFoundError:  # a source tree that was never installed (pip install -e .)
    __version__ = "0.0.0+unknown"
