"""A UAV that stalls: its process lives on but no pose of it reaches the runner for more than a second.

A process stopped with SIGSTOP, starved of CPU, or swapped out does not exit, so the supervisor
sees nothing; its neighbours only see its pose go stale (as they do when a UAV withholds its pose
because its FCU link is lost). :class:`StallWatch` looks at the runner's view of every flying UAV
on each tick: no pose for more than :data:`STALL_AFTER_S` s while the process still runs opens a
stall (from its last pose), the next pose closes it, and each stall is an event of the run
(``stalled``, in run.json, with its duration) and a row of the summary (``stalls``, mrswarm/results/fault_report.py). A UAV whose
process exits is no stall: its exit is the event. Nor is silence the runner cannot tell from its
own blindness: the runner, a client of the edge router, counts a UAV's silence only if its link to
the router has been up since the UAV's last pose (an edge router that dies silences every UAV at
once, and each comes back when its own link to the router does); a runner without a router (a
discovery peer) counts it only while it hears another UAV.
"""

from __future__ import annotations

from mrswarm.records.summary import ProcessEvent

STALL_AFTER_S = 1.0  # s without a pose: what the neighbours' stale_after also waits (uav_stack AgentConfig)
HEARD_S = 0.5  # another UAV heard this recently: the runner's view works


class StallWatch:
    """Open stalls (UAV -> wall time of its last pose) and the events of the ones that ended."""

    def __init__(self, after: float = STALL_AFTER_S):
        self.after = after
        self.open: dict[int, float] = {}

    def tick(self, now: float, last_pose: dict[int, float], flying: set[int],
             path_since: float | None = 0.0) -> tuple[list[int], list[ProcessEvent]]:
        """``last_pose``: each UAV's newest pose at the runner (wall); ``flying``: UAVs whose process runs and flies with
        the swarm; ``path_since``: since when (wall) the runner's link to the edge router has been up (None: it has
        none, or no router: another UAV heard vouches for the runner's view instead). (UAVs that began stalling now,
        events of the stalls that ended now.)"""
        began: list[int] = []
        ended: list[ProcessEvent] = []
        for uav in list(self.open):
            if uav not in flying:  # exited (its own event), or restarted: not a stall
                del self.open[uav]
        for uav in sorted(flying):
            t = last_pose.get(uav)
            if not t:
                continue  # no pose yet: it has not begun
            start = self.open.get(uav)
            if start is not None:
                if t > start:
                    del self.open[uav]
                    ended.append(self._event(uav, start, t, "a pose again"))
            elif now - t > self.after and (path_since <= t if path_since is not None else
                                           any(now - last_pose.get(o, 0.0) < HEARD_S for o in flying if o != uav)):
                self.open[uav] = t
                began.append(uav)
        return began, ended

    def close(self, now: float) -> list[ProcessEvent]:
        """The stalls still open when the run stops, as events up to ``now``."""
        out = [self._event(uav, start, now, "the end of the run") for uav, start in sorted(self.open.items())]
        self.open.clear()
        return out

    @staticmethod
    def _event(uav: int, start: float, end: float, until: str) -> ProcessEvent:
        return ProcessEvent(t=start, name=f"uav{uav}", event="stalled", duration_s=round(end - start, 2),
                            detail=f"no pose for {end - start:.1f} s while its process ran, until {until}")

