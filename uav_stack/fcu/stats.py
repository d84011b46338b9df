"""Counters of one virtual FCU fleet (read them, never reset them mid-run)."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field


@dataclass
class FcuStats:
    datagrams_in: int = 0
    bytes_in: int = 0
    bad_datagrams: int = 0  # unparseable, truncated or CRC-failed datagrams (dropped)
    messages_in: Counter[str] = field(default_factory=Counter)  # by message type
    messages_out: int = 0
    datagrams_out: int = 0
    send_errors: int = 0
    not_for_us: int = 0  # addressed to another system/component
    foreign_datagrams: int = 0  # from another address than the owner's, on an owner-only link (dropped)
    peers_evicted: int = 0  # learned peers replaced by newer ones (never the owner)
    commands: Counter[str] = field(default_factory=Counter)  # by MAV_RESULT name
    commands_by_id: Counter[int] = field(default_factory=Counter)
    # COMMAND_LONGs an ArduPilot cannot take: NaN in param 5 or 6, which it makes integers (its SITL stops on
    # the floating-point trap); the virtual one ignores them, unanswered
    nan_integer_params: int = 0
    handler_errors: int = 0
    handler_errors_by_type: Counter[str] = field(default_factory=Counter)
    physics_steps: int = 0
    dropped_wall_s: float = 0.0  # wall time the sim gave up because the loop was late
    failsafes: Counter[str] = field(default_factory=Counter)

    def as_dict(self) -> dict[str, object]:
        return {
            "datagrams_in": self.datagrams_in,
            "bytes_in": self.bytes_in,
            "bad_datagrams": self.bad_datagrams,
            "messages_in": dict(self.messages_in),
            "messages_out": self.messages_out,
            "datagrams_out": self.datagrams_out,
            "send_errors": self.send_errors,
            "not_for_us": self.not_for_us,
            "foreign_datagrams": self.foreign_datagrams,
            "peers_evicted": self.peers_evicted,
            "commands": dict(self.commands),
            "commands_by_id": dict(self.commands_by_id),
            "nan_integer_params": self.nan_integer_params,
            "handler_errors": self.handler_errors,
            "handler_errors_by_type": dict(self.handler_errors_by_type),
            "physics_steps": self.physics_steps,
            "dropped_wall_s": self.dropped_wall_s,
            "failsafes": dict(self.failsafes),
        }
