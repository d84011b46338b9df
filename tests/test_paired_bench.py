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
