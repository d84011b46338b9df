"""A behaviour's values and message counters onto the network, for the flight recording: :class:`BehaviourReporter`.

What a behaviour records (``ctx.record(name, value)``) is kept as ``(t_wall, name, value)``
samples and sent with its per-topic message counters in one
:class:`~swarmnet.messages.BehaviourReport` on the UAV's own key, ``mrs/<swarm>/<uav>/behaviour``
(access control binds it to the UAV's certificate, like everything it publishes). The agent asks
at every tick (:meth:`BehaviourReporter.due`); a report goes out every :data:`REPORT_PERIOD_S`,
sooner when :data:`MAX_REPORT_SAMPLES` samples wait, but never twice within
:data:`MIN_REPORT_PERIOD_S`. What cannot wait (more samples than a report holds while the
next may not go yet) is dropped and counted, so the UAV's traffic stays bounded: at most
1 / :data:`MIN_REPORT_PERIOD_S` reports a second of at most 32 KiB each. The recorder writes the
samples and the counters on the recording's ``/uav/<N>/behaviour/values`` and
``/uav/<N>/behaviour/topics`` channels (docs/recording.md). A last report goes out when the
agent closes, with what was recorded since the one before. A report that cannot be sent (the
session closing) is counted, never raised.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from swarmnet.messages import MAX_REPORT_SAMPLES, MAX_REPORT_TOPICS, BehaviourReport, TopicCounts, encode_behaviour_report

if TYPE_CHECKING:
    from swarmnet.node import SwarmNode

VALUES_HEADER = "t_wall,name,value\n"  # behaviour_uav<N>.csv: one row per recorded value
REPORT_PERIOD_S = 1.0  # s between two reports
MIN_REPORT_PERIOD_S = 0.25  # s: a full report goes out early, but never more often than this
FINAL_LINGER_S = 0.05  # s the agent's close waits after the last report: a Zenoh session closed at once drops it


class BehaviourReporter:
    """The samples a behaviour recorded since the last report, and the reports' own counts."""

    def __init__(self, uav: int, log: logging.Logger) -> None:
        self.uav = uav
        self.log = log
        self.samples: list[tuple[float, str, float]] = []
        self.dropped = 0  # samples no report carried (the buffer was full)
        self.refused = 0  # ctx.record calls refused (counted by the adapter)
        self.sent = 0
        self.errors = 0
        self.active = False  # something to report: a value recorded (or refused), or message topics
        self._seq = 0
        self._last = -float("inf")  # when the last report went out, s
        self._pub: Any = None
        self._node: SwarmNode | None = None

    def add(self, t: float, name: str, value: float) -> None:
        """A sample (``t``: wall time, s); over a report's worth waiting, dropped and counted."""
        self.active = True
        if len(self.samples) >= MAX_REPORT_SAMPLES:
            self.dropped += 1
            return
        self.samples.append((t, name, value))

    def due(self, now: float) -> bool:
        if not self.active or now - self._last < MIN_REPORT_PERIOD_S:
            return False
        return now - self._last >= REPORT_PERIOD_S or len(self.samples) >= MAX_REPORT_SAMPLES

    def send(self, node: SwarmNode, topics: Mapping[str, TopicCounts], now: float) -> bool:
        """Publish a report now (the samples waiting, the counters as they are); False if it could not be."""
        self._last = now
        samples, self.samples = self.samples, []
        report = BehaviourReport(uav=self.uav, seq=self._seq, t_wall=now, samples=tuple(samples),
                                 topics=dict(list(topics.items())[:MAX_REPORT_TOPICS]), dropped=self.dropped,
                                 refused=self.refused)
        try:
            data = encode_behaviour_report(report)
            if self._pub is None or self._node is not node:
                if node.session is None:
                    raise RuntimeError("the swarm node is closed")
                self._pub = node.session.declare_publisher(node.keys.behaviour(self.uav), express=True)  # 1 Hz: no batching
                self._node = node
            self._pub.put(data)
        except Exception as exc:  # noqa: BLE001 - a report never stops the agent (a closing session raises ZError)
            self.errors += 1
            self.dropped += len(samples)
            if self.errors <= 3 or self.errors % 100 == 0:
                self.log.warning("UAV %d: behaviour report not sent (%d so far): %s: %s", self.uav, self.errors,
                                 type(exc).__name__, exc)
            return False
        self._seq = (self._seq + 1) & 0xFFFFFFFF
        self.sent += 1
        node.stats.sent["behaviour_report"] += 1
        return True

    def as_dict(self) -> dict[str, int]:
        """The stats file's ``behaviour.reports``."""
        return {"sent": self.sent, "errors": self.errors, "values_dropped": self.dropped, "values_refused": self.refused}
