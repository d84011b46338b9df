"""Every bad input of `mrswarm run` exits 2 with a message naming the file and the field (docs/scenarios.md).

Real CLI processes, real files (binary junk, /dev/zero, a FIFO, a folder, an oversized file),
real name resolution; nothing here starts a UAV.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from groundfloor import strict_yaml
from mrswarm.run.resources import check_resources, estimate
from mrswarm.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
MINI = ROOT / "tests" / "scenarios" / "mini_coverage.yaml"


def run(args: list[str], out: Path, timeout: float = 30.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "mrswarm", "run", *args, "--out", str(out), "--no-live"], cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout)


def assert_usage_error(res: subprocess.CompletedProcess[str], *needles: str) -> None:
    text = res.stdout + res.stderr
    assert res.returncode == 2, text
    assert "Traceback" not in text, text
    flat = " ".join(text.split())  # rich wraps long lines
    for n in needles:
        assert n in flat, (n, text)


@pytest.mark.parametrize("override, field, what", [
    ("fleet.count=true", "fleet.count", "must be an integer, got True"),  # a boolean is not a count
    ("fleet.spawn.center=[.nan,0]", "fleet.spawn.center.0", "got nan"),
    ("fleet.spawn.center=[1.0e+7,0]", "fleet.spawn.center.0", "[-50000, 50000]"),
    ("mission.sensor_radius=0.5", "mission.sensor_radius", "coverage cells"),
    ("gcs.mavlink=true", "gcs.host", "cannot resolve 'no-such-host.invalid'"),
    ("faults=[{at: 5, kind: kill_uav, uav: 9}]", "faults.0.uav", "UAV 9 is not in the fleet"),
    ("faults=[{at: 5, kind: gps_jump, uav: 1, duration: 2}]", "faults.0.offset", "required for gps_jump"),
    ("faults=[{at: 25, kind: kill_router}]", "faults.0.at", "not within the mission"),
    ("network.feed_window_ms=-1", "network.feed_window_ms", "must be a number in [0, 1000]"),
])
def test_bad_values_name_the_file_and_field(tmp_path: Path, override: str, field: str, what: str) -> None:
    sets = ["--set", override]
    if override.startswith("mission.sensor_radius"):  # on the largest area allowed (25 km^2)
        sets += ["--set", "mission.area={x_min: -2500, x_max: 2500, y_min: -2500, y_max: 2500}"]
    if override.startswith("gcs.mavlink"):
        sets += ["--set", "gcs.host=no-such-host.invalid"]
    assert_usage_error(run([str(MINI), *sets], tmp_path), str(MINI), field, what)
    assert not list(tmp_path.iterdir()), "a run folder was created for a scenario that does not validate"


def test_an_explicit_uav_list_is_checked_too(tmp_path: Path) -> None:
    for uavs, field, what in (("[{id: 1, start: [0, 0], heading: .inf}]", "uavs.0.heading", "got inf"),
                              ("[{id: 1, start: [1.0e+7, 0]}]", "uavs.0.start.0", "[-50000, 50000]")):
        assert_usage_error(run([str(MINI), "--set", "fleet=null", "--set", f"uavs={uavs}"], tmp_path), str(MINI), field, what)


def test_files_that_are_not_scenarios(tmp_path: Path) -> None:
    junk = tmp_path / "junk.yaml"
    junk.write_bytes(bytes(range(256)) * 4)
    assert_usage_error(run([str(junk)], tmp_path / "o1"), str(junk), "not UTF-8 text")
    big = tmp_path / "big.yaml"
    big.write_text("# " + "x" * (1024 * 1024) + "\n")
    assert_usage_error(run([str(big)], tmp_path / "o2"), str(big), "a scenario is at most 1,048,576 bytes")
    assert_usage_error(run(["/dev/zero"], tmp_path / "o3"), "/dev/zero", "not a regular file (a device)")
    fifo = tmp_path / "fifo.yaml"
    os.mkfifo(fifo)
    assert_usage_error(run([str(fifo)], tmp_path / "o4", timeout=20.0), str(fifo), "not a regular file (a FIFO)")
    assert_usage_error(run([str(tmp_path)], tmp_path / "o5"), str(tmp_path), "not a regular file (a folder)")


def test_what_yaml_cannot_mean_is_refused_naming_the_line(tmp_path: Path) -> None:
    """Two ``duration:`` lines (PyYAML keeps the last without a word) and 5,000 levels of nesting (a
    RecursionError traceback before): exit 2, with the file and the line."""
    text = MINI.read_text()
    twice = tmp_path / "twice.yaml"
    lines = text.splitlines()
    first = next(i for i, line in enumerate(lines) if line.startswith("duration:")) + 1
    twice.write_text(text + "duration: 600\n")
    assert_usage_error(run([str(twice)], tmp_path / "o1"), f"{twice}:{len(lines) + 1}:1",
                       f"duplicate key 'duration' (first on line {first})")
    inner = tmp_path / "inner.yaml"
    inner.write_text(text + "mission_notes: {a: 1, b: 2, a: 3}\n")
    assert_usage_error(run([str(inner)], tmp_path / "o2"), f"{inner}:{len(lines) + 1}:", "duplicate key 'a'")
    deep = tmp_path / "deep.yaml"
    deep.write_text("a: " + "[" * 5000 + "]" * 5000 + "\n")
    assert_usage_error(run([str(deep)], tmp_path / "o3"), f"{deep}:1:", "nested deeper than 64 levels")
    assert_usage_error(run([str(MINI), "--set", "fleet.count={a: 1, a: 2}"], tmp_path / "o4"), "duplicate key 'a'")
    assert not any(p.is_dir() for p in tmp_path.iterdir() if p.name.startswith("o"))
    # YAML's merge keys still override, as YAML says
    assert strict_yaml.load("b: &b {speed: 3.0, alt: 5}\no:\n  <<: *b\n  speed: 4.0\n")["o"] == {"speed": 4.0, "alt": 5}


def test_out_naming_a_file_is_a_usage_error(tmp_path: Path) -> None:
    f = tmp_path / "results"
    f.write_text("not a folder\n")
    assert_usage_error(run([str(MINI)], f), "--out", str(f), "Not a directory")


def test_a_fleet_too_large_for_the_machine_is_refused_with_the_estimate(tmp_path: Path) -> None:
    res = run([str(MINI), "--set", "fleet.count=500", "--set", "fleet.spawn.spacing=6"], tmp_path)
    assert_usage_error(res, str(MINI), "fleet.count: 500 virtual UAVs need about", "cores", "--force")
    big = load_scenario(MINI, ["fleet.count=500", "fleet.spawn.spacing=6"])
    est = estimate(big)
    # 500 UAVs get client mode and the edge feed (scenario.MESH_MAX_UAVS) and pools (fleet.pool auto): a pooled UAV's cost
    assert est.cores_needed == pytest.approx(500 * 0.008) and est.memory_mb_needed == pytest.approx(300 + 500 * 4)
    one_each = estimate(load_scenario(MINI, ["fleet.count=500", "fleet.spawn.spacing=6", "fleet.pool=1"]))
    assert one_each.cores_needed == pytest.approx(500 * 0.025) and one_each.memory_mb_needed == pytest.approx(300 + 500 * 60)
    mesh = estimate(load_scenario(MINI, ["fleet.count=500", "fleet.spawn.spacing=6", "network.pose_feed=direct",
                                         "network.mode=peer", "fleet.pool=1"]))
    assert mesh.cores_needed == pytest.approx(500 * 0.04)
    assert check_resources(load_scenario(MINI)) == ""  # four UAVs fit any machine that runs the tests


def test_pools_never_span_two_mavlink_shards() -> None:
    """A pool's virtual FCU gives its vehicles distinct system ids, so a pool holds the UAVs of one
    shard of 240 (uav_stack/sysid.py): 500 UAVs in pools of 250 fly in pools of 240, 240 and 20,
    and 1,000 UAVs (the fleet's most) by default in pools of at most 240."""
    layout = load_scenario(MINI, ["fleet.count=500", "fleet.pool=250"]).pool_layout()
    assert [(uavs[0], uavs[-1]) for _, uavs in layout] == [(1, 240), (241, 480), (481, 500)]
    big = load_scenario(MINI, ["fleet.count=1000"]).pool_layout()
    assert sum(len(uavs) for _, uavs in big) == 1000 and max(len(uavs) for _, uavs in big) <= 240
    assert all(len({(u - 1) // 240 for u in uavs}) == 1 for _, uavs in big)
