"""The README's first command on a Debian Python: ``scripts/mrswarm run scenarios/coverage.yaml``.

Debian's and Ubuntu's own ``python3`` refuse ``pip install`` (PEP 668) and may have no pip at
all, so ``python3 -m pip install -e .`` fails on a machine that has only Python and apt.
``scripts/mrswarm`` installs into ``./.venv`` there, then runs mrswarm. This flies the README's
scenario, shortened, from a copy of the checkout with the machine's own Debian interpreter, and
asserts what a new user sees: a run that covered ground without collisions, and a second call
that does not install again.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sysconfig
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.e2e


def debian_python() -> str | None:
    """An interpreter >= 3.11 of the machine's own Python that refuses pip installs (PEP 668)."""
    for cand in ("/usr/bin/python3", "/usr/bin/python3.11", "/usr/bin/python3.12", "/usr/bin/python3.13"):
        if not os.access(cand, os.X_OK):
            continue
        probe = subprocess.run(
            [cand, "-c", "import os, sys, sysconfig; print(sys.version_info >= (3, 11) and "
                         "os.path.exists(os.path.join(sysconfig.get_path('stdlib'), 'EXTERNALLY-MANAGED')))"],
            capture_output=True, text=True, timeout=30)
        if probe.stdout.strip() == "True":
            return cand
    return None


def checkout_copy(dest: Path) -> Path:
    """The checkout's files (tracked and new, not ignored) copied to ``dest``, as a fresh clone has them."""
    files = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=ROOT,
                           capture_output=True, check=True, timeout=60).stdout.split(b"\0")
    for name in filter(None, files):
        src = ROOT / os.fsdecode(name)
        if src.is_file():
            (dest / os.fsdecode(name)).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / os.fsdecode(name))
    return dest


def test_first_command_installs_into_a_venv_and_flies_on_debians_python(tmp_path: Path) -> None:
    py = debian_python()
    if py is None:
        pytest.skip("no Debian/Ubuntu python3 (PEP 668, externally managed) on this machine")
    repo = checkout_copy(tmp_path / "mrswarm")
    env = {k: v for k, v in os.environ.items() if k not in ("VIRTUAL_ENV", "PYTHONPATH", "PYTHONHOME")}
    env["PYTHON"] = py
    env["PATH"] = os.pathsep.join(p for p in env.get("PATH", "").split(os.pathsep)
                                  if p != sysconfig.get_path("scripts"))  # not the test's own interpreter's scripts
    try:
        res = subprocess.run(["scripts/mrswarm", "run", "scenarios/coverage.yaml", "--set", "fleet.count=3",
                              "--set", "duration=15", "--no-live", "--out", str(tmp_path / "results")],
                             cwd=repo, env=env, capture_output=True, text=True, timeout=900)
        assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
        assert "making ./.venv" in res.stderr, res.stderr[-2000:]
        assert (repo / ".venv" / "bin" / "python").exists()
        run_dir, = (tmp_path / "results").iterdir()
        summary = json.loads((run_dir / "summary.json").read_text())
        assert summary["uavs_recorded"] == 3
        assert summary["coverage"]["final"] > 0.0
        assert summary["separation"]["collisions"] == 0

        again = subprocess.run(["scripts/mrswarm", "--version"], cwd=repo, env=env, capture_output=True, text=True,
                               timeout=120)
        assert again.returncode == 0, again.stderr[-2000:]
        assert again.stdout.startswith("mrswarm "), again.stdout
        assert "installing" not in again.stderr, again.stderr  # installed once, not at every call
    finally:
        shutil.rmtree(repo / ".venv", ignore_errors=True)  # a few hundred MB
