"""The fault-injection message: codec, acceptance rule, and what a virtual UAV accepts (uav_stack/sim_faults.py)."""

from __future__ import annotations

import math

import msgpack
import pytest

from swarmnet.keyspace import SwarmKeys
from swarmnet.messages import FaultInjection, Kind, Rejected, accept_fault, decode_fault, encode_fault, tag
from uav_stack.sim_faults import check_fault

KEYS = SwarmKeys("alpha")


def test_round_trip_and_key() -> None:
    f = FaultInjection("chaos", 7, 3, "gps_jump", {"dx_m": 8.0, "dy_m": -2, "duration_s": 4.0}, 1_700_000_000.5)
    assert KEYS.fault(3) == "mrs/alpha/3/fault"
    got = accept_fault(KEYS.fault(3), encode_fault(f), me=3)
    assert got == FaultInjection("chaos", 7, 3, "gps_jump", {"dx_m": 8.0, "dy_m": -2.0, "duration_s": 4.0}, 1_700_000_000.5)


def test_a_fault_goes_only_where_its_key_says() -> None:
    data = encode_fault(FaultInjection("chaos", 1, 3, "battery_drop", {"level": 0.1}))
    with pytest.raises(Rejected) as e:
        accept_fault(KEYS.fault(4), data, me=4)  # on UAV 4's key, for UAV 3
    assert e.value.reason == "key_mismatch"
    with pytest.raises(Rejected) as e:
        accept_fault(KEYS.fault(3), data, me=4)
    assert e.value.reason == "wrong_destination"


@pytest.mark.parametrize("args", [{"level": True}, {"level": math.nan}, {"level": "0.1"}, {f"a{i}": 1.0 for i in range(9)},
                                  {"bad name": 1.0}])
def test_bad_arguments_are_refused_on_the_wire(args: dict) -> None:
    raw = msgpack.packb([tag(Kind.FAULT), "chaos", 1, 3, "battery_drop", args, 0])
    with pytest.raises(Rejected):
        decode_fault(raw)
    with pytest.raises(ValueError):
        encode_fault(FaultInjection("chaos", 1, 3, "battery_drop", args))


def test_the_virtual_uav_checks_kind_and_arguments() -> None:
    assert check_fault("fcu_link_loss", {"duration_s": 5.0}) == ""
    assert "unknown fault 'meteor'" in check_fault("meteor", {})
    assert "missing argument duration_s" in check_fault("gps_noise", {"sigma_m": 3.0})
    assert "unknown arguments ['x']" in check_fault("battery_drop", {"level": 0.5, "x": 1.0})
    assert "duration_s=0 outside (0, 600]" in check_fault("fcu_link_loss", {"duration_s": 0.0})
    assert "level=2 outside [0, 1]" in check_fault("battery_drop", {"level": 2.0})
