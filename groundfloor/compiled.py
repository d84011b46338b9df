"""The project's optional compiled modules, loaded one way: present when the install built them, and not asked away.

``setup.py`` builds them (``uav_stack.fcu._dynamics``) when a C compiler and Python's headers are
there (``optional=True``); each has a Python twin that runs the same rules. ``MRSWARM_PURE_PYTHON=1`` in the environment
makes every one of them count as absent, to run (or measure) the Python twins instead; a
comma-separated list of module names (``uav_stack.fcu._dynamics``) makes those absent.
"""

from __future__ import annotations

import importlib
import os
from types import ModuleType


def compiled_module(name: str) -> ModuleType | None:
    """The compiled module ``name`` (``"uav_stack.fcu._dynamics"``...), or None when it was not built
    (no C compiler at install, or built for another Python) or ``MRSWARM_PURE_PYTHON`` names it (or is 1)."""
    pure = os.environ.get("MRSWARM_PURE_PYTHON", "")
    if pure == "1" or name in pure.split(","):
        return None
    try:
        return importlib.import_module(name)
    except ImportError:
        return None
