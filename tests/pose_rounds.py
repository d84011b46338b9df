"""Test helpers for aligned ticks: rounds of poses from real nodes, so that a receiver has heard
every sender at "the instant before" (what :meth:`SwarmNode.expect_poses` counts on).

Every wait is bounded by a timeout.
"""

from __future__ import annotations

import time

from swarmnet.node import SwarmNode
from tests.conftest import wait_for


def publish_pose(n: SwarmNode) -> None:
    """A valid pose of ``n``'s UAV, 5 m up, at y = its id (m)."""
    n.publish_pose(t_sim=0.0, x=0.0, y=float(n.identity.uav), z=5.0, vx=0.0, vy=0.0, vz=0.0, yaw=0.0)


def hear_a_round(receiver: SwarmNode, *senders: SwarmNode, settle_s: float = 0.2) -> None:
    """Publish until ``receiver`` has heard every sender (links or the feed take a moment), let
    the stragglers in, then one clean round: each sender heard within the last pose period."""
    ids = [s.identity.uav for s in senders]

    def heard() -> bool:
        for s in senders:
            publish_pose(s)
        receiver.poll()
        return all(u in receiver.neighbours for u in ids)

    assert wait_for(heard, 10.0, period=0.1)
    time.sleep(settle_s)
    receiver.poll()  # the stragglers
    t_round = time.time()
    for s in senders:
        publish_pose(s)
    assert wait_for(lambda: (receiver.poll(), all(n.last_recv >= t_round for n in receiver.neighbours))[1], 3.0)
