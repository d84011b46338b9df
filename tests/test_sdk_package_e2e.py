"""End to end: a behaviour package of one's own, outside the repository, written by `mrswarm new behaviour`,
installed with pip, flies on 20 virtual UAVs (in two pools, as a large run is) from a scenario naming it by its
import path, with the process and the Docker runtime."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.docker_support import no_leftovers  # noqa: F401 (a fixture)

ROOT = Path(__file__).resolve().parents[1]
NAME = "sdk_e2e_ring"

pytestmark = pytest.mark.e2e


def pip(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "pip", *args], capture_output=True, text=True, timeout=300)


def test_a_package_written_by_mrswarm_new_and_pip_installed_flies_on_20_uavs(tmp_path: Path) -> None:
    res = subprocess.run([sys.executable, "-m", "mrswarm", "new", "behaviour", NAME, "--dir", str(tmp_path)],
                         capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert res.returncode == 0, res.stderr
    pkg = tmp_path / NAME
    assert {p.relative_to(pkg).as_posix() for p in pkg.rglob("*") if p.is_file()} == {
        "pyproject.toml", "README.md", "scenario.yaml", f"{NAME}/__init__.py", f"{NAME}/behaviour.py", f"tests/test_{NAME}.py"}
    # not editable: the UAV processes start without the site module (python -S), which is what reads an editable
    # install's .pth file; a plain install lands in site-packages, which they have on their path
    res = pip("install", "--no-deps", "-q", str(pkg))
    assert res.returncode == 0, res.stdout + res.stderr
    try:
        elsewhere = tmp_path / "elsewhere"  # neither the repository nor the package's folder: only the install finds it
        elsewhere.mkdir()
        listed = subprocess.run([sys.executable, "-c", "from uav_stack.sdk import loader; print(loader.registered())"],
                                capture_output=True, text=True, timeout=60, cwd=elsewhere)
        assert f"'{NAME}': '{NAME}.behaviour:SdkE2eRing'" in listed.stdout, listed.stdout + listed.stderr
        out = tmp_path / "runs"
        res = subprocess.run([sys.executable, "-m", "mrswarm", "run", str(pkg / "scenario.yaml"), "--set", "fleet.count=20",
                              "--set", "fleet.pool=10", "--set", "mission.params.radius=40",
                              "--set", "duration=25", "--out", str(out), "--no-live",
                              "--no-record", "--log-level", "WARNING"],
                             capture_output=True, text=True, timeout=600, cwd=elsewhere)
        assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
        run_dir = next(out.iterdir())
        summary = json.loads((run_dir / "summary.json").read_text())
        assert summary["uavs_recorded"] == 20 and summary["separation"]["collisions"] == 0
        b = summary["behaviour"]
        assert b["behaviours"] == [f"{NAME}.behaviour:SdkE2eRing"] and b["uavs"] == 20 and b["stopped"] == []
        assert b["faults"] == {"exceptions": 0, "overruns": 0, "bad_intents": 0}
        hello = b["topics"][f"{NAME}/hello"]
        assert hello["received"] > 20 * 19 and hello["rejected"] == 0
        for uav in range(1, 21):
            st = json.loads((run_dir / f"uav{uav}.json").read_text())
            assert st["phase"] == "mission" and st["behaviour"]["values"]["heard"] == 19.0, (uav, st["behaviour"])
    finally:
        pip("uninstall", "-y", "-q", NAME.replace("_", "-"))


@pytest.fixture(scope="module")
def sdk_image() -> str:
    """The stack image of this checkout under a tag of its own (the SDK's tests never retag mrswarm:<version>)."""
    from deploy.images import ImageError, default_base, ensure_image

    try:
        from tests.docker_support import docker_client

        return ensure_image(tag="mrswarm-sdk-test:dev", base=default_base(docker_client()), log=lambda m: None).tag
    except ImageError as exc:
        pytest.fail(f"cannot build the stack image: {exc}", pytrace=False)


@pytest.mark.docker
def test_the_docker_runtime_carries_the_package_into_the_uav_containers(tmp_path: Path, sdk_image: str,
                                                                       no_leftovers: None) -> None:
    res = subprocess.run([sys.executable, "-m", "mrswarm", "new", "behaviour", NAME, "--dir", str(tmp_path)],
                         capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert res.returncode == 0, res.stderr
    res = pip("install", "--no-deps", "-q", str(tmp_path / NAME))
    assert res.returncode == 0, res.stdout + res.stderr
    try:
        elsewhere = tmp_path / "elsewhere"
        elsewhere.mkdir()
        out = tmp_path / "runs"
        res = subprocess.run([sys.executable, "-m", "mrswarm", "run", str(tmp_path / NAME / "scenario.yaml"),
                              "--runtime", "docker", "--set", f"docker.image={sdk_image}", "--set", "mission.behaviour=" + NAME,
                              "--set", "fleet.count=20", "--set", "duration=20", "--out", str(out), "--no-live", "--no-record",
                              "--log-level", "WARNING"],
                             capture_output=True, text=True, timeout=600, cwd=elsewhere)
        assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
        run_dir = next(out.iterdir())
        summary = json.loads((run_dir / "summary.json").read_text())
        assert summary["uavs_recorded"] == 20 and summary["separation"]["collisions"] == 0
        b = summary["behaviour"]
        assert b["behaviours"] == [NAME] and b["uavs"] == 20 and b["stopped"] == []
        for uav in range(1, 21):
            st = json.loads((run_dir / f"uav{uav}.json").read_text())
            assert st["phase"] == "mission" and st["behaviour"]["values"]["heard"] == 19.0, (uav, st["behaviour"])
    finally:
        pip("uninstall", "-y", "-q", NAME.replace("_", "-"))
