"""``mrswarm new behaviour NAME``: a package of one's own swarm algorithm, ready to install and fly (docs/sdk.md).

It writes ``NAME/``: ``pyproject.toml`` (the package, and its behaviour registered in the
``mrswarm.behaviours`` entry-point group under NAME), ``NAME/behaviour.py`` (a behaviour that
spreads the swarm on a ring and says hello over messages), ``scenario.yaml`` (it on 5 virtual
UAVs) and ``tests/test_NAME.py`` (a headless flight with :mod:`mrswarm.testing`). Then::

    pip install ./NAME          # or pip install -e ./NAME on a companion computer
    mrswarm run NAME/scenario.yaml
    pytest NAME/tests
"""

from __future__ import annotations

import argparse
import keyword
import re
import sys
from pathlib import Path

from uav_stack.sdk.loader import ENTRY_POINT_GROUP

_NAME = re.compile(r"^[a-z][a-z0-9_]{0,39}$")


def class_name(name: str) -> str:
    """``my_flock`` -> ``MyFlock``."""
    return "".join(p.capitalize() for p in name.split("_") if p)


def name_problem(name: str) -> str:
    """"" if ``name`` can be a package's and a behaviour's name, else why not."""
    if not _NAME.match(name):
        return "use 1-40 characters of [a-z0-9_], starting with a letter (it becomes the Python package's name)"
    if keyword.iskeyword(name) or name in sys.stdlib_module_names or name in ("mrswarm", "uav_stack", "swarmnet", "examples"):
        return f"{name!r} is taken by Python or mrswarm; choose another"
    return ""


PYPROJECT = '''[build-system]
requires = ["setuptools>=61"]
build-backend = "setuptools.build_meta"

[project]
name = "{dist}"
version = "0.1.0"
description = "{cls}: a swarm behaviour for mrswarm"
requires-python = ">=3.11"
dependencies = []  # mrswarm itself is on every UAV already

[project.entry-points."{group}"]
{name} = "{name}.behaviour:{cls}"

[tool.setuptools]
packages = ["{name}"]
'''

BEHAVIOUR = '''"""{cls}: spread out on a ring around the swarm's start, and say hello to the others.

A starting point for a behaviour of your own (docs/sdk.md): its parameters, a message type, a step.
"""

from __future__ import annotations

import math

import msgspec

from mrswarm.api import Behaviour, Context, GoTo


class {cls}Params(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    radius: float = 15.0  # m, the ring's radius
    centre: tuple[float, float] = (0.0, 0.0)  # m, ENU


class Hello(msgspec.Struct, frozen=True):
    n: int  # how many the sender has heard so far


class {cls}(Behaviour[{cls}Params]):
    """Each UAV flies to its own slot of a ring (by its rank among the members) and broadcasts a hello."""

    Params = {cls}Params
    messages = {{"{name}/hello": Hello}}
    rate_hz = 5.0

    def setup(self, ctx: Context) -> None:
        self.heard: set[int] = set()

    def step(self, ctx: Context) -> GoTo:
        for m in ctx.inbox("{name}/hello"):
            self.heard.add(m.src)
        ctx.send("{name}/hello", Hello(len(self.heard)))
        ctx.record("heard", len(self.heard))
        members = ctx.members or (ctx.uav,)
        a = 2.0 * math.pi * members.index(ctx.uav) / len(members) if ctx.uav in members else 0.0
        cx, cy = self.params.centre
        return GoTo(cx + self.params.radius * math.cos(a), cy + self.params.radius * math.sin(a))
'''

SCENARIO = '''# {cls} on 5 virtual UAVs: mrswarm run scenario.yaml (with the package installed: pip install .)
name: {name}
swarm: {swarm}
seed: 1
duration: 30
origin: {{lat: 46.6167, lon: 14.2650, alt: 446.0}}
flight: {{altitude: 10, speed: 5.0, safety_distance: 5.0, collision_distance: 1.0}}
mission:
  behaviour: {name}.behaviour:{cls}  # or its registered name: {name}
  params: {{radius: 15.0}}
fleet:
  count: 5
  spawn: {{pattern: grid, spacing: 10, center: [0, 0]}}
'''

TEST = '''"""{cls} flown headless on virtual UAVs (mrswarm.testing): on its ring, every hello heard, no collision."""

from __future__ import annotations

import math
from pathlib import Path

from mrswarm.testing import fly

SCENARIO = Path(__file__).resolve().parents[1] / "scenario.yaml"


def test_{name}_spreads_on_its_ring_and_hears_everyone(tmp_path: Path) -> None:
    flight = fly(scenario=SCENARIO, out=tmp_path, sets=["duration=25"])
    assert flight.collisions == 0 and flight.incidents == []
    ids = sorted(flight.trajectories)
    for uav in ids:
        x, y, _ = flight.trajectories[uav].last
        assert abs(math.hypot(x, y) - 15.0) < 2.0, (uav, x, y)
        assert flight.last_value(uav, "heard") == len(ids) - 1
'''

README = '''# {name}

A swarm behaviour for [mrswarm](https://github.com/) (its docs/sdk.md): `{name}/behaviour.py`.

    pip install .                  # into the environment mrswarm runs from
    mrswarm run scenario.yaml      # 5 virtual UAVs; the results folder has the summary and the plot
    pytest tests                   # a headless flight, asserted
    mrswarm agent --behaviour {name} ...   # on a real UAV's companion computer, with this package installed
'''


def write_package(name: str, where: Path) -> Path:
    """The package of behaviour ``name`` in ``where/name``; ValueError if the name is unusable or the folder exists."""
    problem = name_problem(name)
    if problem:
        raise ValueError(f"{name}: {problem}")
    root = where / name
    if root.exists():
        raise ValueError(f"{root} exists already: choose another name or folder")
    cls = class_name(name)
    fields = {"name": name, "cls": cls, "dist": name.replace("_", "-"), "group": ENTRY_POINT_GROUP,
              "swarm": name.replace("_", "-")[:32]}
    files = {
        "pyproject.toml": PYPROJECT,
        f"{name}/__init__.py": f'"""{cls}: a swarm behaviour for mrswarm."""\n',
        f"{name}/behaviour.py": BEHAVIOUR,
        "scenario.yaml": SCENARIO,
        f"tests/test_{name}.py": TEST,
        "README.md": README,
    }
    for rel, text in files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text.format(**fields))
    return root


def main(argv: list[str] | None = None) -> int:
    from uav_stack.cli_args import ArgumentParser

    ap: argparse.ArgumentParser = ArgumentParser(prog="mrswarm new", description="write a new package from a template")
    sub = ap.add_subparsers(dest="what", required=True, metavar="WHAT")
    p = sub.add_parser("behaviour", help="a swarm behaviour of the SDK: pyproject, behaviour, scenario, test (docs/sdk.md)")
    p.add_argument("name", help="its name: the Python package's and the registered behaviour's (e.g. my_flock)")
    p.add_argument("--dir", default=".", help="where to write the package's folder (default: here)")
    args = ap.parse_args(argv)
    try:
        root = write_package(args.name, Path(args.dir))
    except ValueError as exc:
        ap.error(str(exc))
    except OSError as exc:
        ap.error(f"--dir {args.dir}: {exc.strerror or exc}")
    print(f"wrote {root}/: pyproject.toml, {args.name}/behaviour.py, scenario.yaml, tests/test_{args.name}.py\n"
          f"next: pip install {root} && mrswarm run {root}/scenario.yaml")
    return 0
