"""A run whose host could not keep up says so (summary.saturated; `mrswarm run` exits 4)."""

from __future__ import annotations

from typing import Any

from mrswarm.results.saturation import saturation_reasons


def _stats(late: int, ticks: int = 1000, netem_class: str | None = None) -> dict[int, dict[str, Any]]:
    links = {"2": {"class": netem_class}} if netem_class else {}
    return {u: {"loop": {"period_s": 0.1, "ticks": ticks, "late": late, "worst_late_s": 0.42},
                "netem": {"config": "off", "links": links}} for u in (1, 2, 3)}


def test_a_host_that_kept_up_is_not_flagged() -> None:
    assert saturation_reasons(0.001, _stats(late=10)) == []


def test_late_ticks_say_the_machine_could_not_keep_up() -> None:
    why = saturation_reasons(0.0, _stats(late=200))
    assert len(why) == 1 and "20.0 % of their ticks" in why[0] and "worst 420 ms" in why[0]


def test_lost_poses_count_only_where_no_impairment_was_asked_for() -> None:
    assert any("34.0 % of poses lost" in w for w in saturation_reasons(0.34, _stats(late=0)))
    assert saturation_reasons(0.34, _stats(late=0, netem_class="lte")) == []  # a netem profile's losses are the experiment's
    # with spatial interest a far neighbour's poses come at the far rate: their gaps are the filter's
    assert saturation_reasons(0.34, _stats(late=0), interest=True) == []
    assert len(saturation_reasons(0.34, _stats(late=200), interest=True)) == 1  # late ticks still say so
