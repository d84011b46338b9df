"""The ground floor (groundfloor/): one copy of each shared helper, and every package built on it.

Real files, real processes and real signals; the error-root check reads the sources with
``ast``, as tests/test_layers.py does, so it needs no package importable.
"""

from __future__ import annotations

import ast
import json
import math
import os
import re
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from groundfloor.errors import MrswarmError, Rejected
from groundfloor.files import replacing, write_atomic, write_json_atomic
from groundfloor.histogram import LogHistogram
from groundfloor.process import STOP_SIGNALS, die_with_parent_preexec, on_stop_signals
from tests.test_layers import LAYERS, ROOT

BUILTIN_ERRORS = {"Exception", "ValueError", "RuntimeError", "OSError", "TimeoutError", "KeyError", "TypeError",
                  "LookupError", "ConnectionError", "IOError"}
NOT_ERRORS = {"Interrupted"}  # mrswarm.run.signals: a stop request, which an `except MrswarmError` must not swallow


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
    from groundfloor.schema import ConfigError
    from mrswarm.recorder.mcap_writer import DiskError
    from swarmnet.messages import DecodeError

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


# ---- process helpers: real processes, real signals -------------------------------------------------
def alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie nobody reaped yet has ended)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state not in ("Z", "X")


def wait_gone(pid: int, timeout: float = 20.0) -> bool:
    deadline = time.monotonic() + timeout
    while alive(pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    return not alive(pid)


# a launcher that starts a sleeper (both ways of asking to die with the parent), prints its pid, then waits
LAUNCHER = """
import os, subprocess, sys, time
from groundfloor.process import die_with_parent_preexec
sleeper = "import sys, time\\nfrom groundfloor.process import die_with_parent\\n" + (
    "die_with_parent()\\n" if sys.argv[1] == "self" else "") + "print('ready', flush=True)\\ntime.sleep(120)\\n"
preexec = die_with_parent_preexec(os.getpid()) if sys.argv[1] == "preexec" else None
child = subprocess.Popen([sys.executable, "-c", sleeper], stdout=subprocess.PIPE, text=True, preexec_fn=preexec)
assert child.stdout is not None and child.stdout.readline() == "ready\\n"
print(child.pid, flush=True)
time.sleep(120)
"""


@pytest.mark.parametrize("how", ["preexec", "self"])
def test_a_child_dies_with_its_parent_even_on_sigkill(how: str) -> None:
    launcher = subprocess.Popen([sys.executable, "-c", LAUNCHER, how], stdout=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        assert launcher.stdout is not None
        child = int(launcher.stdout.readline())
        assert alive(child)
        launcher.kill()  # SIGKILL: the launcher cannot clean up after itself
        launcher.wait(10)
        assert wait_gone(child), f"the {how} child outlived its parent"
    finally:
        launcher.kill()


def test_a_child_whose_parent_is_gone_before_exec_exits() -> None:
    # a parent pid that is not ours: as if the parent had died between fork and exec
    proc = subprocess.run([sys.executable, "-c", "print('ran')"], preexec_fn=die_with_parent_preexec(os.getpid() + 10**7),
                          capture_output=True, text=True, timeout=30)
    assert (proc.returncode, proc.stdout) == (1, "")


STOPPER = """
import signal, sys
from groundfloor.process import stop_event
stop = stop_event()
print('ready', flush=True)
print('stopped' if stop.wait(60) else 'timed out', flush=True)
"""


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_stop_signal_sets_the_event_and_the_loop_ends_cleanly(sig: int) -> None:
    proc = subprocess.Popen([sys.executable, "-c", STOPPER], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=ROOT)
    try:
        assert proc.stdout is not None and proc.stdout.readline() == "ready\n"
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=30)
        assert (proc.returncode, out, err) == (0, "stopped\n", "")
    finally:
        proc.kill()


def test_on_stop_signals_returns_what_it_replaced() -> None:
    before = {s: signal.getsignal(s) for s in STOP_SIGNALS}
    seen: list[int] = []
    old = on_stop_signals(lambda signum, frame: seen.append(signum))
    try:
        assert old == before
        signal.raise_signal(signal.SIGTERM)
        assert seen == [signal.SIGTERM]
    finally:
        for s, h in old.items():
            signal.signal(s, h)


# ---- atomic writes: real files, a real full disk (/dev/full) and a read-only folder -----------------
def test_write_atomic_replaces_the_whole_file_and_leaves_nothing_beside_it(tmp_path: Path) -> None:
    path = tmp_path / "summary.json"
    write_atomic(path, b"old")
    write_atomic(path, "new: \u00e9", fsync=True)
    write_json_atomic(tmp_path / "c.json", {"rx": [1, 2]}, indent=1)
    assert path.read_text() == "new: \u00e9"
    assert json.loads((tmp_path / "c.json").read_text()) == {"rx": [1, 2]}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.json", "summary.json"]
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~current_umask()


def current_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_a_private_file_is_the_owners_only_from_the_first_byte(tmp_path: Path) -> None:
    path = tmp_path / "node.key"
    old = os.umask(0)  # the most permissive umask: 0600 must not depend on it
    try:
        with replacing(path, private=True) as f:
            assert stat.S_IMODE(os.fstat(f.fileno()).st_mode) == 0o600
            f.write(b"secret")
    finally:
        os.umask(old)
    assert stat.S_IMODE(path.stat().st_mode) == 0o600 and path.read_bytes() == b"secret"


def test_a_failed_write_keeps_the_old_file_and_no_temporary_one(tmp_path: Path) -> None:
    path = tmp_path / "world.json"
    write_atomic(path, "old")
    with pytest.raises(RuntimeError), replacing(path) as f:
        f.write(b"half of the new")
        raise RuntimeError("the writer failed midway")
    assert path.read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["world.json"]
    # the kernel refuses the write past 1 kB (RLIMIT_FSIZE: EFBIG), as a full disk refuses it (ENOSPC)
    refused = subprocess.run([sys.executable, "-c", FILE_LIMITED, str(path)], capture_output=True, text=True, cwd=ROOT,
                             timeout=30)
    assert (refused.returncode, refused.stdout, refused.stderr) == (0, "EFBIG\n", "")
    assert path.read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["world.json"]


FILE_LIMITED = """
import errno, resource, signal, sys
from groundfloor.files import write_atomic
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
resource.setrlimit(resource.RLIMIT_FSIZE, (1000, 1000))
try:
    write_atomic(sys.argv[1], b"x" * 100_000)
except OSError as exc:
    print(errno.errorcode[exc.errno])
"""


# ---- the histogram -----------------------------------------------------------------------------------
def test_percentiles_are_within_one_bin_of_the_exact_ones_and_survive_a_merge_through_json() -> None:
    rng = np.random.default_rng(7)
    ages = rng.lognormal(mean=math.log(0.004), sigma=1.0, size=5000)  # seconds: ~4 ms pose ages
    first, second = LogHistogram(), LogHistogram()
    for v in ages[:3000]:
        first.add(float(v))
    second.add_many(LogHistogram.indices(ages[3000:]), ages[3000:])
    merged = LogHistogram.from_dict(json.loads(json.dumps(first.to_dict())))
    merged.merge(second)
    width = 10 ** (1 / LogHistogram.PER_DECADE)  # one bin, as a ratio
    for q in (50, 99):
        exact = float(np.percentile(ages, q, method="inverted_cdf"))
        assert exact <= merged.percentile(q) <= exact * width
        assert exact / width <= merged.centre_percentile(q) <= exact * width
    assert merged.n == 5000 and merged.max == float(ages.max()) and math.isclose(merged.mean, float(ages.mean()))
    assert math.isnan(LogHistogram().percentile(50)) and math.isnan(LogHistogram().centre_percentile(99))


# ---- one copy: the helpers above are not written again in a package above ---------------------------
ONE_COPY = {  # what a package above writes only by calling groundfloor: pattern -> where it lives
    r"\bos\.replace\(": "groundfloor.files (write_atomic, replacing)",
    r"\.chmod\(0o600\)": "groundfloor.files (write_atomic with private=True: owner-only from the first byte)",
    r"\bprctl\b": "groundfloor.process (die_with_parent, die_with_parent_preexec)",
    r"^Addr\b[^=]*=": "groundfloor.net",
    r"\blogging\.basicConfig\(": "groundfloor.process.setup_logging",
    r"^class (Rejected|MrswarmError)\b": "groundfloor.errors",
}
# uav_stack/fcu/ is being restructured on another branch; these go when it imports groundfloor's
PENDING: set[tuple[str, str]] = set()


def test_each_shared_helper_is_written_once() -> None:
    again = []
    for pkg in LAYERS[1:]:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            rel = path.relative_to(ROOT)
            if "results" in rel.parts or "_generated" in rel.parts:
                continue
            for n, line in enumerate(path.read_text().splitlines(), 1):
                code = line.split("#", 1)[0].rstrip()
                for pattern, home in ONE_COPY.items():
                    if re.search(pattern, code) and (str(rel), pattern) not in PENDING:
                        again.append(f"{rel}:{n}: {code.strip()!r}: call {home}")
    assert not again, "helpers written again:\n" + "\n".join(again)
