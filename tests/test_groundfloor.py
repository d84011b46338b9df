"""The ground floor (groundfloor/): one copy of each shared helper, and every package built on it.

Real files, real processes and real signals; the error-root check reads the sources with
``ast``, as tests/test_layers.py does, so it needs no package importable.
"""

from __future__ import annotations

import ast
from pathlib import Path

from groundfloor.errors import MrswarmError, Rejected
from tests.test_layers import LAYERS, ROOT

BUILTIN_ERRORS = {"Exception", "ValueError", "RuntimeError", "OSError", "TimeoutError", "KeyError", "TypeError",
                  "LookupError", "ConnectionError", "IOError"}
NOT_ERRORS = {"Interrupted"}  # mrswarm.signals: a stop request, which an `except MrswarmError` must not swallow


def exception_classes(root: Path = ROOT, packages: tuple[str, ...] = LAYERS) -> dict[str, tuple[str, set[str]]]:
    """Every class of the packages that is an exception: name -> (where, names of its bases, transitively)."""
    classes: dict[str, tuple[str, list[str]]] = {}
    for pkg in packages:
        for path in sorted((root / pkg).rglob("*.py")):
            rel = path.relative_to(root)
            if "results" in rel.parts or "_generated" in rel.parts:
                continue
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if isinstance(node, ast.ClassDef):
                    classes[node.name] = (f"{rel}:{node.lineno}", [ast.unparse(b).split(".")[-1] for b in node.bases])

    def ancestors(name: str, seen: frozenset[str] = frozenset()) -> set[str]:
        bases = set(classes[name][1]) if name in classes and name not in seen else set()
        return bases.union(*(ancestors(b, seen | {name}) for b in bases))

    out = {}
    for name, (where, _) in classes.items():
        up = ancestors(name)
        if up & (BUILTIN_ERRORS | {"MrswarmError"}):
            out[name] = (where, up)
    return out


def rootless(errors: dict[str, tuple[str, set[str]]]) -> list[str]:
    return [f"{where} {name}" for name, (where, up) in sorted(errors.items())
            if "MrswarmError" not in up and name not in NOT_ERRORS and name != "MrswarmError"]


def test_every_error_class_derives_from_the_root() -> None:
    errors = exception_classes()
    assert {"ConfigError", "Rejected", "DecodeError", "ProtocolError", "ScenarioError", "DeployError"} <= set(errors)
    assert not rootless(errors), "error classes without MrswarmError among their bases:\n" + "\n".join(rootless(errors))


def test_the_root_keeps_what_each_error_was() -> None:
    from discovery.protocol import ProtocolError
    from mrswarm.recorder.mcap_writer import DiskError
    from swarmnet.messages import DecodeError
    from swarmnet.schema import ConfigError

    disk = DiskError(28, "No space left on device")
    assert isinstance(disk, OSError) and isinstance(disk, MrswarmError) and disk.errno == 28
    assert str(disk) == "[Errno 28] No space left on device"
    for exc in (ConfigError("fleet.count", "must be an integer"), DecodeError("malformed"), ProtocolError("bad_mac")):
        assert isinstance(exc, ValueError) and isinstance(exc, MrswarmError)
    assert isinstance(ProtocolError("bad_mac"), Rejected) and isinstance(DecodeError("oversized"), Rejected)


def test_a_rejection_names_its_counter() -> None:
    exc = Rejected("wrong_uav", "key says uav 3, payload uav 4")
    assert (exc.reason, exc.detail, str(exc)) == ("wrong_uav", "key says uav 3, payload uav 4",
                                                 "wrong_uav: key says uav 3, payload uav 4")
    assert str(Rejected("malformed")) == "malformed"


def test_the_checker_sees_a_rootless_error(tmp_path: Path) -> None:
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "m.py").write_text("from groundfloor.errors import MrswarmError\n\n"
                                           "class Base(ValueError):\n    pass\n\nclass Deep(Base):\n    pass\n\n"
                                           "class Good(OSError, MrswarmError):\n    pass\n\nclass Plain:\n    pass\n")
    errors = exception_classes(tmp_path, ("pkg",))
    assert set(errors) == {"Base", "Deep", "Good"}
    assert rootless(errors) == ["pkg/m.py:3 Base", "pkg/m.py:6 Deep"]
