"""The flight state machine's transition table: every phase has a way on, and a way down."""

from __future__ import annotations

from collections import deque

from uav_stack.flight import ANYTIME, TRANSITIONS
from uav_stack.phases import CONTROLLED, AgentPhase


def _reachable(start: AgentPhase) -> set[AgentPhase]:
    seen, todo = {start}, deque([start])
    while todo:
        for nxt in TRANSITIONS[todo.popleft()] | ANYTIME:
            if nxt not in seen:
                seen.add(nxt)
                todo.append(nxt)
    return seen


def test_every_phase_has_a_row_in_the_table() -> None:
    assert set(TRANSITIONS) == set(AgentPhase)
    for row in TRANSITIONS.values():
        assert row <= set(AgentPhase)


def test_a_uav_can_go_from_power_on_to_its_mission_and_every_phase_back_to_the_ground() -> None:
    assert AgentPhase.MISSION in _reachable(AgentPhase.INIT)
    for phase in AgentPhase:
        if phase is not AgentPhase.INIT:
            assert AgentPhase.LANDED in _reachable(phase), phase


def test_someone_else_can_take_over_from_every_phase_under_swarm_control() -> None:
    for phase in CONTROLLED | {AgentPhase.TAKEOFF, AgentPhase.OFFBOARD}:
        assert AgentPhase.YIELDED in TRANSITIONS[phase], phase
    assert AgentPhase.OFFBOARD in TRANSITIONS[AgentPhase.YIELDED]  # and the agent can take control back
