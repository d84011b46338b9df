"""The packages form layers, and imports never point up (docs/architecture.md).

groundfloor (bottom) -> swarmnet -> discovery -> uav_stack -> world -> deploy -> mrswarm -> benchmarks: a module may
import from its own package or a lower one. Every import counts, also one inside a function
or under ``TYPE_CHECKING``: either would break when the layers are split or reused. The test
reads the source with ``ast``, so it needs no package importable.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LAYERS = ("groundfloor", "swarmnet", "discovery", "uav_stack", "world", "deploy", "mrswarm", "benchmarks")
RANK = {name: i for i, name in enumerate(LAYERS)}


def imported_packages(path: Path) -> list[tuple[int, str]]:
    """(line, top-level package) of every absolute import in a file that names one of our packages."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        else:
            continue
        out += [(node.lineno, n.split(".")[0]) for n in names if n.split(".")[0] in RANK]
    return out


def package_imports() -> dict[str, dict[str, list[str]]]:
    """importer package -> imported package -> where (``file:line``)."""
    graph: dict[str, dict[str, list[str]]] = {p: {} for p in LAYERS}
    for pkg in LAYERS:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            if "results" in path.relative_to(ROOT).parts:
                continue
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
