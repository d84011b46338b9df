"""A pooled UAV whose agent raised is an incident of the run (its pool logged it and flew on)."""

from __future__ import annotations

from mrswarm.results.behaviour_report import pool_agent_incidents


def test_a_pooled_uavs_agent_errors_become_an_incident_at_the_first_one() -> None:
    stats = {
        3: {"pool": {"agent_errors": 57, "first_error": {"t": 1012.5, "what": "act", "error": "NameError: name 'x'"}}},
        4: {"pool": {"agent_errors": 0, "first_error": None}},  # a pool-mate that never raised
        5: {},  # a UAV of its own process
        6: {"pool": {"agent_errors": 2, "first_error": "garbled"}},  # a stats file from elsewhere: still counted
    }
    got = pool_agent_incidents(stats, t0=1000.0)
    assert [(i.uav, i.kind) for i in got] == [(3, "agent_error"), (6, "agent_error")]
    assert got[0].t_s == 12.5 and "57 times" in got[0].detail and "act: NameError" in got[0].detail
    assert got[1].t_s == 0.0 and "2 times" in got[1].detail
