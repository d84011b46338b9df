"""The pieces of benchmarks/paired.py a reader of its figures relies on, with real processes: the
CPU a process used, read in nanoseconds from the scheduler, and the halves of the fleet."""

from __future__ import annotations

import subprocess
import sys
import time

from benchmarks.paired import b_flies, thread_ns, window_ns

# burns 0.4 s of CPU on its main thread and 0.2 s on a second thread, then both sleep
BURNER = """
import threading, time
def burn(s):
    end = time.thread_time() + s
    while time.thread_time() < end:
        pass
done = threading.Event()
t = threading.Thread(target=lambda: (burn(0.2), done.set(), time.sleep(30)), daemon=True); t.start()
burn(0.4); done.wait()
print("done", flush=True)
time.sleep(30)
"""


def test_thread_ns_counts_the_cpu_of_every_thread_of_a_process() -> None:
    proc = subprocess.Popen([sys.executable, "-c", BURNER], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "done"
        first = thread_ns(proc.pid)
        assert first is not None and len(first) == 2
        assert 0.6e9 <= sum(first.values()) <= 1.5e9  # 0.6 s burnt, plus the interpreter's start
        assert max(first.values()) >= 0.4e9 and min(first.values()) >= 0.2e9  # each thread its own
        time.sleep(0.3)  # asleep: it uses (almost) nothing more
        second = thread_ns(proc.pid)
        assert second is not None and 0 <= window_ns(first, second) < 0.05e9
    finally:
        proc.kill()
        proc.wait()
    assert thread_ns(proc.pid) is None  # gone: no reading, rather than a zero


def test_b_flies_half_the_fleet_and_the_other_half_in_the_next_round() -> None:
    names = [f"uav{i}" for i in range(1, 11)]
    first = {n for n in names if b_flies(n, 0)}
    second = {n for n in names if b_flies(n, 1)}
    assert len(first) == len(second) == 5 and first.isdisjoint(second)
    assert first == {n for n in names if b_flies(n, 2)}


def test_commits_fly_first_in_turn_so_that_the_order_costs_every_side_alike() -> None:
    """benchmarks/commits.py: the side flown second in a round measured about 4 % more, so over two
    rounds every side flies first once and second once, each with its own index kept."""
    from benchmarks.commits import flying_order

    sides = [("a", "py"), ("b", "py"), ("c", "py")]
    rounds = [flying_order(sides, rnd) for rnd in range(4)]
    assert rounds[0] == rounds[2] == [(0, sides[0]), (1, sides[1]), (2, sides[2])]
    assert rounds[1] == rounds[3] == [(2, sides[2]), (1, sides[1]), (0, sides[0])]
    for k in range(len(sides)):  # each side's place, summed over a pair of rounds, is the same
        assert sum([i for i, _ in r].index(k) for r in rounds[:2]) == len(sides) - 1


def test_pose_instants_reads_when_the_poses_of_an_instant_left(tmp_path) -> None:
    """scale.py's pose_instants, on a flight record written as mrswarm's recorder writes poses:
    three UAVs whose poses leave 1, 3 and 9 ms after each instant, and their status files."""
    import json

    from mcap.writer import Writer

    from benchmarks.scale import pose_instants

    with open(tmp_path / "run.mcap", "wb") as f:
        w = Writer(f)
        w.start()
        schema = w.register_schema("pose", "jsonschema", b"{}")
        channels = {u: w.register_channel(f"/uav/{u}/pose", "json", schema) for u in (1, 2, 3)}
        for k in range(100, 120):  # twenty instants, 0.1 s apart
            for u, after in ((1, 0.001), (2, 0.003), (3, 0.009)):
                t = k * 0.1 + after
                w.add_message(channels[u], int(t * 1e9), json.dumps({"uav": u, "t_wall": t}).encode(), int(t * 1e9))
        w.finish()
    for u, (batches, poses) in {1: (30, 40), 2: (20, 40), 3: (40, 40)}.items():  # 1.5, 1.0, 2.0 batches an instant
        (tmp_path / f"uav{u}.json").write_text(json.dumps({"uav": u, "net": {"received": {"pose_batch": batches,
                                                                                          "pose": poses}}}))
    got = pose_instants(tmp_path, 3)
    assert abs(got["pose_sent_after_instant_p50_ms"] - 3.0) < 0.01
    assert 3.0 < got["pose_sent_after_instant_p90_ms"] <= 9.0
    assert abs(got["instant_spread_p50_ms"] - 8.0) < 0.01
    assert got["feed_batches_per_instant"] == 1.5
