"""Arming, the first phase of a flight: into a mode the autopilot arms in, past its pre-arm checks, armed.

:class:`Arming` is the ``arming`` phase of :class:`uav_stack.flight.Flight`: it keeps the
phase's timers (how long it has tried, when the last arm went out) and says, in the autopilot's
own words, why an arm or a mode change was refused. Once armed in a mode that takes off it hands
back to the flight (:meth:`Flight.take_off`); after ``failsafe.arm_timeout_s`` it gives up
(phase ``error``; a takeoff or start tries again).
"""

from __future__ import annotations

import logging
import math
from typing import TYPE_CHECKING

from uav_stack.mav import mavlink

if TYPE_CHECKING:
    from uav_stack.fcu_link import CommandHandle
    from uav_stack.flight import Flight

log = logging.getLogger(__name__)

RETRY_AFTER = 1.5  # s: a refused or unanswered arm, mode, takeoff or land command is sent again after this
PREARM_PROBE_S = 10.0  # s: while the autopilot reports failing pre-arm checks, an arm is tried this often (its answer says why)
CONFIRM_S = 1.5  # s an accepted arm or mode change may take to show in the heartbeat (ArduPilot: its next 1 Hz beat)


class Arming:
    """The arming phase's timers and refusals; :meth:`step` runs once per control tick while arming."""

    def __init__(self, timeout_s: float):
        self.timeout_s = timeout_s  # s of arming before giving up (failsafe.arm_timeout_s)
        self.counters = {"arm_refused": 0, "arm_gave_up": 0}
        self._since = -math.inf  # when the phase began
        self._sent_at = -math.inf  # when the phase's current command was first sent
        self._arm_at = -math.inf  # when the last arm was sent
        self._tries = 0
        self._refusal: CommandHandle | None = None  # the refused command already reported

    def begin(self, now: float) -> None:
        """A new arming phase: the first arm goes at once if the pre-arm checks pass; while they
        fail, the first probe after PREARM_PROBE_S."""
        self._since = self._arm_at = now
        self._tries = 0
        self._refusal = None

    def step(self, flight: Flight, now: float) -> None:
        """Arm, then take off. First out of any mode the autopilot cannot arm in (its profile's
        ``arm_modes``: PX4 returns to OFFBOARD after a landing), then once its own pre-arm checks
        pass (SYS_STATUS); a refusal is reported with the autopilot's reason and the arm tried
        again, for ``timeout_s`` at most."""
        st = flight.link.state
        prof = st.profile
        if st.armed:
            need = prof.takeoff_mode if prof.takeoff_mode not in (None, st.mode) else None  # ArduPilot: GUIDED
            if need is None:
                flight.take_off(now)
                return
        else:
            need = None if st.mode in prof.arm_modes else prof.arming_mode
        if now - self._since > self.timeout_s:
            self._give_up(flight)
            return
        if self._waiting(flight, need, now):
            return
        if need is not None:
            h = flight.command
            if h is None or h.command != mavlink.MAV_CMD_DO_SET_MODE or h.accepted:
                flight.say(f"switching from {st.mode} to {need} to arm "
                           f"({prof.label} arms in {', '.join(sorted(prof.arm_modes))})")
            self._send(flight, flight.link.set_mode(need), now)
            return
        if self._checks_pending(flight, now):
            return
        self._arm_at = now
        self._tries += 1
        self._send(flight, flight.link.arm(True), now)

    def _give_up(self, flight: Flight) -> None:
        self.counters["arm_gave_up"] += 1
        why = flight.detail or "no answer"
        log.error("UAV %d: not armed after %.0f s: %s", flight.uav, self.timeout_s, why)
        flight.give_up_arming(f"not armed after {self.timeout_s:.0f} s (takeoff or start tries again): {why}")

    def _waiting(self, flight: Flight, need: str | None, now: float) -> bool:
        """True while the last command's answer, or its effect, is still to come."""
        h = flight.command
        if h is None:
            return False
        if not h.done:
            return True  # its answer is pending (FcuLink retries it)
        if h.accepted and now - self._sent_at < CONFIRM_S:
            return True  # accepted: give the heartbeat time to show it
        if not h.accepted:
            if self._refusal is not h:
                self._refused(flight, h, need, now)
            if now - self._sent_at < RETRY_AFTER:
                return True
        return False

    def _checks_pending(self, flight: Flight, now: float) -> bool:
        """True (and the detail says why) while the autopilot is not ready to be armed."""
        link = flight.link
        st = link.state
        if not st.has_position:
            flight.say(f"waiting for a position: {st.no_position}")
            return True
        if st.prearm_ok is None and link.contract.pending("SYS_STATUS"):
            flight.say("waiting for the autopilot's SYS_STATUS (its pre-arm checks)")
            return True
        if st.prearm_ok is False and now - self._arm_at < PREARM_PROBE_S:
            reasons = (st.reasons_since(now - 30.0) + [f"PX4 reports: {c}" for c in st.px4_checks])[-3:]
            flight.say("waiting for the autopilot's pre-arm checks (SYS_STATUS)" + (f": {'; '.join(reasons)}" if reasons else ""))
            return True
        return False

    def _send(self, flight: Flight, h: CommandHandle, now: float) -> None:
        flight.command = h
        flight.since = now
        self._sent_at = now

    def _refused(self, flight: Flight, h: CommandHandle, need: str | None, now: float) -> None:
        """Say why the autopilot refused the arming phase's command, in its own words."""
        self._refusal = h
        st = flight.link.state
        arming = h.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM
        reasons = st.reasons_since(self._sent_at - 0.05)
        if st.px4_checks and any(r.startswith("commander_arm_denied") for r in reasons):
            reasons.append(f"PX4 reports: {', '.join(st.px4_checks)}")
        what = f"arm {h.status}" if arming else f"switch to {need} {h.status}"
        if arming:
            self.counters["arm_refused"] += 1
            what += f" ({self._tries} tr{'y' if self._tries == 1 else 'ies'} in {now - self._since:.0f} s)"
        detail = f"{what}: {'; '.join(reasons) if reasons else 'the autopilot gave no reason'}"
        new_reason = detail.split(": ", 1)[-1] != flight.detail.split(": ", 1)[-1]
        log.log(logging.WARNING if new_reason else logging.INFO, "UAV %d: %s", flight.uav, detail)
        flight.detail = detail
        flight.changed = True
