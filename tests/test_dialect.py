"""mrswarm's MAVLink dialect parses every frame real ArduPilot and PX4 firmware send."""

from __future__ import annotations

import collections

import pytest

from tests import captures
from uav_stack.mav import mavlink

CAPTURES = [(ap, c) for ap in (captures.ARDUPILOT, captures.PX4)
            for c in sorted(p.name for p in (captures.ROOT / ap).iterdir() if (p / "capture.tlog").is_file())]


@pytest.mark.parametrize(("autopilot", "capture"), CAPTURES, ids=[f"{a}/{c}" for a, c in CAPTURES])
def test_every_frame_of_real_firmware_parses_as_its_own_message(autopilot: str, capture: str) -> None:
    kinds: collections.Counter[str] = collections.Counter()
    for frame in captures.frames(autopilot, capture):
        kinds[frame.msg.get_type()] += 1
    unknown = {k: n for k, n in kinds.items() if k.startswith(("UNKNOWN_", "BAD_DATA"))}
    assert not unknown, f"{autopilot}/{capture}: frames the dialect cannot parse: {unknown}"
    assert kinds["HEARTBEAT"] > 0


def test_the_messages_common_lacks_are_there() -> None:
    # ArduPilot's own, and PX4 1.16's ids from its common.xml (pymavlink's common has none of them)
    for name in ("EKF_STATUS_REPORT", "AHRS", "AHRS2", "SIMSTATE", "MEMINFO", "WIND",
                 "EVENT", "CURRENT_EVENT_SEQUENCE", "LINK_NODE_STATUS", "TIME_ESTIMATE_TO_TARGET", "CURRENT_MODE"):
        assert hasattr(mavlink, f"MAVLINK_MSG_ID_{name}"), name
    px4 = {f.msg.get_type() for f in captures.frames(captures.PX4, "boot_passive")}
    assert {"EVENT", "CURRENT_EVENT_SEQUENCE", "LINK_NODE_STATUS", "TIME_ESTIMATE_TO_TARGET", "CURRENT_MODE"} <= px4
