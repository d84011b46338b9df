"""A behaviour package of one's own carried into the UAV containers (docs/sdk.md).

The stack image holds mrswarm only. A scenario's behaviour from another package (an installed
one, or a folder on the runner's import path) is found on the host, where the runner imported
it at the scenario's load, and bind-mounted read-only into every UAV container under
:data:`BEHAVIOURS_IN_CONTAINER`, which is the containers' ``PYTHONPATH``: the package's folder,
and its ``.dist-info`` when it is an installed distribution (so its entry points, the
registered names, are found there too). Nothing is baked into the image. A pure-Python package
works so; one with compiled extensions needs them built for the image's Python (3.11).
"""

from __future__ import annotations

import importlib.util
from importlib import metadata
from pathlib import Path

from uav_stack.sdk.loader import registered

BEHAVIOURS_IN_CONTAINER = "/opt/mrswarm-behaviours"
# the packages of the image's own wheel: never mounted over
IN_IMAGE = frozenset({"mrswarm", "groundfloor", "swarmnet", "uav_stack", "discovery", "world", "deploy"})


def behaviour_package(spec: str) -> str:
    """The top-level package a behaviour's spec (``package.module:Class`` or a registered name) imports."""
    path = spec if ":" in spec else registered().get(spec, spec)
    return path.partition(":")[0].split(".")[0]


def behaviour_mounts(spec: str | None) -> dict[str, str]:
    """Host path -> path in the container of what a UAV container needs to import behaviour ``spec``
    (empty: the image has it, or there is no behaviour). ValueError if the host cannot find it."""
    if not spec:
        return {}
    top = behaviour_package(spec)
    if top in IN_IMAGE:
        return {}
    found = importlib.util.find_spec(top)
    if found is None or (found.origin is None and not found.submodule_search_locations):
        raise ValueError(f"behaviour {spec}: package {top!r} not found on this host")
    if found.submodule_search_locations:  # a package (a namespace package: its first folder)
        where = Path(next(iter(found.submodule_search_locations)))
    else:  # a single-file module
        assert found.origin is not None
        where = Path(found.origin)
    mounts = {str(where.resolve()): f"{BEHAVIOURS_IN_CONTAINER}/{where.name}"}
    for dist_name in metadata.packages_distributions().get(top, []):
        try:
            dist = metadata.distribution(dist_name)
        except metadata.PackageNotFoundError:
            continue
        for f in dist.files or []:
            if f.name == "METADATA" and f.parent.name.endswith(".dist-info"):
                info = Path(str(dist.locate_file(f))).parent
                if info.is_dir():
                    mounts[str(info.resolve())] = f"{BEHAVIOURS_IN_CONTAINER}/{info.name}"
                break
    return mounts
