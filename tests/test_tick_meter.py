"""The tick meter (uav_stack/tick_meter.py) on a real virtual UAV process: asked for by its
environment variable, it accounts for the loop's ticks part by part, and the UAV flies as it
does without it."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest

from tests.conftest import wait_for
from tests.gcs_helpers import agent_stats, start_virtual_uav, stop_process
from uav_stack import tick_meter

pytestmark = pytest.mark.e2e


def _airborne(tmp: Path) -> bool:
    try:
        return agent_stats(tmp, 1)["phase"] == "mission"
    except (OSError, ValueError, KeyError):
        return False


def test_the_meter_accounts_for_a_flying_uavs_ticks(tmp_path: Path, router: str, monkeypatch: pytest.MonkeyPatch) -> None:
    meter_dir = tmp_path / "meter"
    meter_dir.mkdir()
    monkeypatch.setenv(tick_meter.ENV, str(meter_dir))
    proc = start_virtual_uav(tmp_path, router, autostart=True)
    try:
        assert wait_for(lambda: _airborne(tmp_path), 40, 0.2), (tmp_path / "uav1.log").read_text()[-3000:]
        time.sleep(4.0)  # some ticks in flight
    finally:
        stop_process(proc)
    assert proc.returncode == 0, (tmp_path / "uav1.log").read_text()[-3000:]
    report = json.loads((meter_dir / "tick_uav1.json").read_text())
    parts = {p["part"]: p for p in report["parts"]}
    assert set(parts) == {label for label, _, _ in tick_meter.PARTS}  # every part was found on the live objects

    # ten ticks a second over the run, each with one sense and two FCU reads
    assert 0.8 * 10 * report["wall_s"] <= report["ticks"] <= 1.1 * 10 * report["wall_s"] + 2
    assert parts[tick_meter.SENSE]["calls_per_tick"] == 1.0
    assert parts["fcu: datagrams in (and steps due)"]["calls_per_tick"] == pytest.approx(2.0, abs=0.05)
    # the own pose left on most ticks (not before the first position), the counters file once a second
    assert parts["agent: own pose published (Zenoh put)"]["calls_per_tick"] > 0.5
    assert parts["agent: counters file, flushes (1 Hz)"]["calls_per_tick"] == pytest.approx(0.1, abs=0.03)

    # the scheduler's account of the loop thread agrees with the thread's own CPU clock, and
    # Zenoh's runtime threads (the session with the router) ran beside it
    threads = report["threads_us_per_tick"]
    assert set(threads) == {"loop", "python", "zenoh"}
    assert threads["loop"] == pytest.approx(report["thread_cpu_us_per_tick"], rel=0.1)
    assert threads["zenoh"] > 0 and threads["python"] >= 0

    # the parts that run one after the other in the loop fit within the loop thread's CPU
    outer = ["fcu: datagrams in (and steps due)", "fcu: service (steps, heartbeat, wake-up)", tick_meter.SENSE,
             "agent: act (swarm in, control, reports)", "loop: poses of the instant expected",
             "loop: sleep until the next instant (select)"]
    assert 0 < sum(parts[p]["cpu_us_per_tick"] for p in outer) <= report["thread_cpu_us_per_tick"]
    # a nested part costs no more than the part that calls it
    def us(part: str) -> float:
        return float(parts[part]["cpu_us_per_tick"])

    assert us("fcu: telemetry encoded and queued") <= us("fcu: steps due (physics, supervisor, telemetry)")
    assert us("agent: control (behaviour, setpoint out)") <= us("agent: act (swarm in, control, reports)")

    # and the UAV flew as usual: its records were written, its setpoints reached the FCU
    stats = agent_stats(tmp_path, 1)
    assert stats["fcu_link"]["tx_setpoints"] > 20
    assert stats["records"]["files_not_written"] == 0
