"""The packages form layers, and imports never point up (docs/architecture.md).

groundfloor (bottom) -> swarmnet -> discovery -> uav_stack -> world -> deploy -> mrswarm -> benchmarks: a module may
import from its own package or a lower one. Every import counts, also one inside a function
or under ``TYPE_CHECKING``: either would break when the layers are split or reused. The test
reads the source with ``ast``, so it needs no package importable.
"""

from __future__ import annotations

import ast
import graphlib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LAYERS = ("groundfloor", "swarmnet", "discovery", "uav_stack", "world", "deploy", "mrswarm", "benchmarks")
RANK = {name: i for i, name in enumerate(LAYERS)}
# mrswarm's own rooms, bottom to top (docs/architecture.md): a room imports from itself or a lower one.
ROOMS = ("scenario", "records", "recorder", "results", "run", "gcs", "sweep", "cli")
ROOM_RANK = {name: i for i, name in enumerate(ROOMS)}


def is_measured(path: Path) -> bool:
    """Our source, not a benchmark's committed results."""
    return path.relative_to(ROOT).parts[:2] != ("benchmarks", "results")


def imported_modules(path: Path) -> list[tuple[int, str]]:
    """(line, dotted name) of every absolute import in a file: ``from mrswarm import cli`` names ``mrswarm.cli``."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out += [(node.lineno, f"{node.module}.{a.name}") for a in node.names]
    return out


def imported_packages(path: Path) -> list[tuple[int, str]]:
    """(line, top-level package) of every absolute import in a file that names one of our packages."""
    found = dict.fromkeys((line, name.split(".")[0]) for line, name in imported_modules(path))
    return [(line, pkg) for line, pkg in found if pkg in RANK]


def package_imports() -> dict[str, dict[str, list[str]]]:
    """importer package -> imported package -> where (``file:line``)."""
    graph: dict[str, dict[str, list[str]]] = {p: {} for p in LAYERS}
    for pkg in LAYERS:
        for path in sorted(p for p in (ROOT / pkg).rglob("*.py") if is_measured(p)):
            for line, dep in imported_packages(path):
                if dep != pkg:
                    graph[pkg].setdefault(dep, []).append(f"{path.relative_to(ROOT)}:{line}")
    return graph


def test_no_import_points_up_a_layer() -> None:
    graph = package_imports()
    upward = [f"{where} imports {dep} ({pkg} is below it)" for pkg, deps in graph.items() if pkg != "benchmarks"
              for dep, places in deps.items() if RANK[dep] > RANK[pkg] for where in places]
    assert not upward, "imports that point up a layer:\n" + "\n".join(upward)


def test_no_cycle_between_packages() -> None:
    graph = {pkg: set(deps) for pkg, deps in package_imports().items()}
    cycles = []
    for start in LAYERS:  # a path back to start through the package graph
        stack, seen = [(start, [start])], set()
        while stack:
            node, path = stack.pop()
            for nxt in graph[node]:
                if nxt == start:
                    cycles.append(" -> ".join(path + [start]))
                elif nxt not in seen:
                    seen.add(nxt)
                    stack.append((nxt, path + [nxt]))
    assert not cycles, "package cycles:\n" + "\n".join(sorted(set(cycles)))


def test_the_checker_sees_an_upward_import(tmp_path: Path) -> None:
    bad = tmp_path / "m.py"
    bad.write_text("def f():\n    from mrswarm.scenario import Scenario\n    import uav_stack.config, json\n")
    assert imported_packages(bad) == [(2, "mrswarm"), (3, "uav_stack")]


def room_imports(path: Path) -> list[tuple[int, str]]:
    """(line, room) of every import of a file that names one of mrswarm's rooms."""
    found = dict.fromkeys((line, name.split(".")[1]) for line, name in imported_modules(path) if name.startswith("mrswarm."))
    return [(line, room) for line, room in found if room in ROOM_RANK]


def test_every_room_of_mrswarm_has_its_place_in_the_order() -> None:
    """A new sub-package of mrswarm is placed in ROOMS (and docs/architecture.md), not left out of the check."""
    rooms = sorted(p.name for p in (ROOT / "mrswarm").iterdir() if (p / "__init__.py").is_file())
    assert rooms == sorted(ROOMS), f"rooms: {rooms}; in the order: {sorted(ROOMS)}"


def test_no_import_points_up_a_room_of_mrswarm() -> None:
    """results never imports run or cli, run never imports cli, the records and the scenario import no room above."""
    upward = []
    for path in sorted((ROOT / "mrswarm").rglob("*.py")):
        parts = path.relative_to(ROOT / "mrswarm").parts
        if len(parts) == 1:  # the package's face (__init__.py, __main__.py, a public entry point) may use every room
            continue
        upward += [f"{path.relative_to(ROOT)}:{line} imports mrswarm.{room} ({parts[0]} is below it)"
                   for line, room in room_imports(path) if ROOM_RANK[room] > ROOM_RANK[parts[0]]]
    assert not upward, "imports that point up a room:\n" + "\n".join(upward)


def test_the_checker_sees_an_upward_room_import(tmp_path: Path) -> None:
    bad = tmp_path / "m.py"
    bad.write_text("def f():\n    from mrswarm.run.experiment import Experiment\n    from mrswarm import cli\n")
    assert room_imports(bad) == [(2, "run"), (3, "cli")]


def module_name(path: Path, root: Path = ROOT) -> str:
    parts = path.relative_to(root).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def module_imports(root: Path, packages: tuple[str, ...]) -> dict[str, set[str]]:
    """module -> the modules of ours it imports when it is imported: its top-level statements (one under an ``if``,
    such as ``TYPE_CHECKING``, is left out, and one inside a function runs later and closes no circle).
    ``from pkg import sub`` is an import of ``pkg.sub``."""
    paths = {module_name(p, root): p for pkg in packages for p in sorted((root / pkg).rglob("*.py"))
             if p.relative_to(root).parts[:2] != ("benchmarks", "results")}  # fmt: skip
    graph: dict[str, set[str]] = {}
    for mod, path in paths.items():
        deps: set[str] = set()
        for node in ast.parse(path.read_text(), str(path)).body:
            if isinstance(node, ast.Import):
                deps |= {a.name for a in node.names if a.name in paths}
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                subs = {f"{node.module}.{a.name}" for a in node.names}
                deps |= subs & paths.keys()
                if not subs <= paths.keys() and node.module in paths:
                    deps.add(node.module)
        graph[mod] = deps - {mod}
    return graph


def import_circle(graph: dict[str, set[str]]) -> list[str]:
    """One circle of imports (its modules in order, the first repeated at the end), or [] when there is none."""
    try:
        graphlib.TopologicalSorter(graph).prepare()
    except graphlib.CycleError as e:
        return list(e.args[1])
    return []


def test_no_circle_of_imports_between_modules() -> None:
    """Modules that import each other work only in one import order, and cannot be read or reused one at a time."""
    circle = import_circle(module_imports(ROOT, LAYERS))
    assert not circle, "a circle of module-level imports: " + " -> ".join(circle)


def test_the_checker_sees_a_circle_of_imports(tmp_path: Path) -> None:
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "__init__.py").write_text("")
    (tmp_path / "pkg" / "agent.py").write_text("from pkg import failsafe\n")
    (tmp_path / "pkg" / "failsafe.py").write_text("import json\nfrom pkg.agent import Agent\n")
    (tmp_path / "pkg" / "lazy.py").write_text("def f():\n    from pkg.agent import Agent\n")
    graph = module_imports(tmp_path, ("pkg",))
    assert graph["pkg.agent"] == {"pkg.failsafe"} and graph["pkg.lazy"] == set()
    assert set(import_circle(graph)) == {"pkg.agent", "pkg.failsafe"}
