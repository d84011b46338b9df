"""MAVLink 2 datagrams of the FCU link, parsed by pymavlink one whole datagram at a time.

Every frame is packed and parsed by pymavlink itself: a compiled pass for the plain messages
saved less than it cost to keep (docs/performance.md, "The compiled path").

* :meth:`MAVLink.parse_datagram` parses one datagram with pymavlink's ``parse_buffer`` after
  resetting its parser, so a bad or cut frame never spills into the next datagram.
* :class:`MAVLink` is pymavlink's ``MAVLink`` with it. The FCU's vehicles and the agent's FCU
  link use it.
"""

from __future__ import annotations

from typing import Any

from uav_stack.mav import mavlink


class MAVLink(mavlink.MAVLink):
    """pymavlink's ``MAVLink`` for a link of whole datagrams (:meth:`parse_datagram`). Counters
    (``total_packets_sent``, ``total_packets_received``...) and callbacks are pymavlink's own."""

    def parse_datagram(self, data: bytes) -> list[Any]:
        """The messages of one datagram (it holds whole frames, so nothing carries over from the last).

        pymavlink returns bad data as ``MAVLink_bad_data`` and may raise on some corrupt frames."""
        self._reset()
        return self.parse_buffer(data) or []

    def _reset(self) -> None:
        """pymavlink's parser as new: no partial frame carries over into the next datagram."""
        self.buf = bytearray()
        self.buf_index = 0
        self.expected_length = mavlink.HEADER_LEN_V1 + 2
        self.have_prefix_error = False
