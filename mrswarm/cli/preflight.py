"""``mrswarm preflight --fcu URL``: does this flight controller give the agent what it needs?

It opens the agent's own FCU link (:class:`~uav_stack.fcu_link.FcuLink`, so its start-up contract,
:mod:`uav_stack.fcu_contract`, and its readiness rules are the agent's, not a second copy), listens,
reads a few parameters and prints one table: heartbeat, autopilot and version, whether the
autopilot hears the link, each stream the agent needs (asked for with ``--set-streams``, as the
agent asks at start-up), GPS, estimator, position, pre-arm checks, the offboard mode, the
companion- and GCS-link-loss failsafes, signing. Each failing row names the parameter or command
that fixes it. Exit 0 when nothing fails, 1 when a check fails, 2 on bad input (docs/fcu.md).
"""

from __future__ import annotations

import argparse
import json
import math
import struct
import sys
import time
from dataclasses import asdict, dataclass
from typing import Any

from uav_stack.autopilot import AutopilotProfile
from uav_stack.fcu_link import FcuLink, LinkOpenError
from uav_stack.mav import mavlink

PASS, WARN, FAIL = "pass", "warn", "fail"
PARAM_TRIES = 3
PARAM_WAIT_S = 1.0

# what to set on ArduPilot so that a message streams without being asked (MAVn_ of the port, n = 1 the first)
ARDUPILOT_STREAM_PARAMS = {
    "GLOBAL_POSITION_INT": "MAV1_POSITION", "SYS_STATUS": "MAV1_EXT_STAT", "GPS_RAW_INT": "MAV1_EXT_STAT",
    "EKF_STATUS_REPORT": "MAV1_EXTRA3",
}
PARAM_ALIASES = {"MAV_GCS_SYSID": "SYSID_MYGCS"}  # ArduPilot 4.7's name: the name before it
PX4_OFFBOARD_LOSS_ACTIONS = {0: "Position mode", 1: "Altitude mode", 2: "Manual", 3: "Return", 4: "Land", 5: "Hold",
                             6: "Terminate", 7: "Disarm"}
PX4_DLL_ACTIONS = {0: "disabled", 1: "Hold", 2: "Return", 3: "Land", 5: "Terminate", 6: "Disarm"}
ARDUPILOT_FS_GCS = {0: "disabled", 1: "RTL", 2: "continue the mission in AUTO, else RTL", 3: "SmartRTL or RTL",
                    4: "SmartRTL or Land", 5: "Land", 6: "Auto DO_LAND_START or RTL", 7: "Brake or Land"}


@dataclass
class Check:
    name: str
    result: str  # pass | warn | fail
    found: str
    fix: str = ""


class ParamReader:
    """PARAM_REQUEST_READ by name over the link, each answered by a PARAM_VALUE (or not: then None)."""

    def __init__(self, link: FcuLink, names: list[str]):
        self.link = link
        self.values: dict[str, float | None] = dict.fromkeys(names)
        self.raw: dict[str, tuple[float, int]] = {}
        self.tries = dict.fromkeys(names, 0)
        self.asked_at = dict.fromkeys(names, -math.inf)

    def on_message(self, msg: Any) -> None:
        if msg.get_type() == "PARAM_VALUE":
            name = msg.param_id.rstrip("\x00") if isinstance(msg.param_id, str) else ""
            if name in self.values:
                self.raw[name] = (msg.param_value, msg.param_type)

    def service(self, now: float) -> None:
        for name in self.values:
            if name not in self.raw and self.tries[name] < PARAM_TRIES and now - self.asked_at[name] >= PARAM_WAIT_S:
                self.tries[name] += 1
                self.asked_at[name] = now
                self.link.conn.mav.param_request_read_send(self.link.target, mavlink.MAV_COMP_ID_AUTOPILOT1,
                                                           name.encode(), -1)

    @property
    def done(self) -> bool:
        return all(n in self.raw or self.tries[n] >= PARAM_TRIES for n in self.values)

    def value(self, name: str, profile: AutopilotProfile) -> float | None:
        """The parameter's value; PX4 sends integers bytewise in the float, ArduPilot casts them."""
        got = self.raw.get(name)
        if got is None:
            return None
        value, ptype = got
        if ptype in (mavlink.MAV_PARAM_TYPE_INT32, mavlink.MAV_PARAM_TYPE_UINT32, mavlink.MAV_PARAM_TYPE_INT16,
                     mavlink.MAV_PARAM_TYPE_UINT16, mavlink.MAV_PARAM_TYPE_INT8, mavlink.MAV_PARAM_TYPE_UINT8):
            if profile.name == "px4":
                return float(struct.unpack("<i", struct.pack("<f", value))[0])
            return float(round(value))
        return float(value)


def _params_for(profile: AutopilotProfile) -> list[str]:
    if profile.name == "px4":
        return ["NAV_DLL_ACT", "COM_DL_LOSS_T", "COM_OF_LOSS_T", "COM_OBL_RC_ACT"]
    return ["FS_GCS_ENABLE", "FS_GCS_TIMEOUT", "MAV_GCS_SYSID", "SYSID_MYGCS", "GUID_TIMEOUT"]


def run_preflight(url: str, *, sysid: int = 250, set_streams: bool = False, timeout: float = 10.0, listen: float = 8.0,
                  bind: str | None = None) -> list[Check]:
    """Connect, listen for ``listen`` s after the first heartbeat, and return the checks."""
    signed = [0]

    def seen(msg: Any) -> None:
        if msg.get_header().incompat_flags & mavlink.MAVLINK_IFLAG_SIGNED:
            signed[0] += 1
        if reader is not None:
            reader.on_message(msg)

    reader: ParamReader | None = None
    link = FcuLink(url, source_system=sysid, ask_streams=set_streams, on_message=seen, bind=bind).open()
    try:
        deadline = time.time() + timeout
        while link.fcu_ids is None and time.time() < deadline:
            _pump(link)
        if link.fcu_ids is None:
            return [Check("heartbeat", FAIL, f"no autopilot heartbeat in {timeout:g} s ({link.counts['rx']} messages)",
                          "check --fcu: udpin:HOST:PORT where the autopilot sends, udpout:HOST:PORT where it listens, "
                          "serial:/dev/ttyACM0:921600; and the autopilot's MAVLink port (ArduPilot SERIALn_PROTOCOL=2, "
                          "PX4 MAV_n_CONFIG)")]
        profile = link.state.profile
        reader = ParamReader(link, _params_for(profile))
        end = time.time() + listen
        while time.time() < end or not reader.done:
            reader.service(time.time())
            _pump(link)
            if time.time() > end + PARAM_TRIES * PARAM_WAIT_S + 1.0:
                break
        return _checks(link, reader, set_streams, signed[0])
    finally:
        link.close()


def _pump(link: FcuLink) -> None:
    link.poll()
    link.service()
    time.sleep(0.02)


def _checks(link: FcuLink, params: ParamReader, set_streams: bool, signed: int) -> list[Check]:
    st, c = link.state, link.contract
    prof = st.profile
    ids = link.fcu_ids or (0, 0)
    out = [Check("heartbeat", PASS, f"sysid {ids[0]} compid {ids[1]}: {prof.label}, mode {st.mode}, "
                                    f"{'armed' if st.armed else 'disarmed'}, system status {st.system_status}")]
    if st.version:
        out.append(Check("autopilot", PASS, f"{prof.label} {st.version}"))
    else:
        out.append(Check("autopilot", WARN, "no AUTOPILOT_VERSION", "the autopilot did not answer REQUEST_MESSAGE(148)"))
    if c.version_ack:
        out.append(Check("commands answered", PASS if c.version_ack == "accepted" else WARN,
                         f"REQUEST_MESSAGE answered: {c.version_ack}"))
    else:
        out.append(Check("commands answered", FAIL, "no COMMAND_ACK to REQUEST_MESSAGE: the autopilot does not hear this link",
                         "check the link's transmit side (serial TX, the udpout address) and that the autopilot does not "
                         "require signing on this port"))
    for name, s in c.streams.items():
        w = s.want
        hz = "none" if math.isnan(s.hz) or s.hz == 0 else f"{s.hz:.1f} Hz"
        found = f"{hz} (needs {w.hz:g} Hz: {w.why})"
        if s.status == "ok":
            out.append(Check(name, PASS, found + (f"; asked {s.tries}x" if s.tries else "")))
            continue
        result = FAIL if w.required else WARN
        if not set_streams:
            param = ARDUPILOT_STREAM_PARAMS.get(name)
            fix = "the agent asks for it at start-up: mrswarm preflight --set-streams checks that it then comes"
            if param and prof.name == "ardupilot":
                fix += f"; to stream it unasked set {param}={math.ceil(w.hz)} (SR0_* before ArduPilot 4.7)"
            out.append(Check(name, result, found, fix))
        elif s.status == "refused":
            out.append(Check(name, result, c.describe(s), "" if not w.required else "a firmware that sends it"))
        else:
            out.append(Check(name, result, c.describe(s),
                             "the autopilot ignored SET_MESSAGE_INTERVAL" + (" and REQUEST_DATA_STREAM" if prof.data_streams
                                                                           else "") + ": see its MAVLink port's settings"))
    if st.gps_fix < 0:
        out.append(Check("GPS", WARN, "no GPS_RAW_INT", "run with --set-streams"))
    elif st.gps_fix >= mavlink.GPS_FIX_TYPE_3D_FIX:
        out.append(Check("GPS", PASS, f"3D fix (fix_type {st.gps_fix}, {st.satellites} satellites)"))
    else:
        out.append(Check("GPS", FAIL, f"no 3D fix (fix_type {st.gps_fix}, {st.satellites} satellites)",
                         "wait for the fix with a clear sky; check the GPS (ArduPilot GPS1_TYPE, PX4 GPS_1_CONFIG)"))
    if st.estimator_flags >= 0:
        out.append(Check("estimator", PASS if "estimator" not in st.no_position else FAIL,
                         f"{st.estimator} flags 0x{st.estimator_flags:x}" + (
                             "" if "estimator" not in st.no_position else f": {st.no_position.split('(', 1)[-1].rstrip(')')}"),
                         "" if "estimator" not in st.no_position else "wait until the EKF uses GPS (ArduPilot says "
                                                                       "'EKF3 IMU0 is using GPS')"))
    else:
        out.append(Check("estimator", WARN, f"no {prof.estimator or 'estimator flags'}: the position is trusted on the GPS fix",
                         "" if set_streams else "run with --set-streams"))
    if st.has_position:
        out.append(Check("position", PASS, f"{st.lat:.6f}, {st.lon:.6f}, {st.alt:.1f} m AMSL"))
    else:
        out.append(Check("position", FAIL, st.no_position, "the agent waits in init until the autopilot has a position"))
    pre = st.prearm_ok
    armable = st.mode in prof.arm_modes
    if pre is None:
        out.append(Check("pre-arm checks", WARN, "no SYS_STATUS", "" if set_streams else "run with --set-streams"))
    elif pre:
        out.append(Check("pre-arm checks", PASS, f"pass (SYS_STATUS) in {st.mode}"))
    else:
        reasons = (st.reasons_since(-math.inf) + [f"PX4 reports: {x}" for x in st.px4_checks])[-3:]
        found = f"fail in {st.mode}" + (f": {'; '.join(reasons)}" if reasons else "")
        if not armable:
            out.append(Check("pre-arm checks", WARN, found,
                             f"{prof.label} does not arm in {st.mode}: the agent switches to {prof.arming_mode} first"))
        else:
            out.append(Check("pre-arm checks", FAIL, found, "the autopilot's own message says what fails (ArduPilot "
                                                            "'PreArm: ...', PX4's events; QGroundControl shows both)"))
    out.append(_offboard(st.capabilities, prof))
    out += _failsafes(params, prof)
    if signed:
        out.append(Check("signing", WARN, f"{signed} signed frames from the autopilot",
                         "the agent's FCU link is unsigned (a local link): allow unsigned messages on this port"))
    else:
        out.append(Check("signing", PASS, "unsigned frames: the agent's local FCU link needs none (ground stations: "
                                          "docs/security.md)"))
    return out


def _offboard(capabilities: int, prof: AutopilotProfile) -> Check:
    name = f"{prof.offboard_mode} setpoints"
    if capabilities < 0:
        return Check(name, WARN, "unknown (no AUTOPILOT_VERSION)")
    if capabilities & mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED:
        return Check(name, PASS, f"{prof.label} takes SET_POSITION_TARGET_LOCAL_NED in {prof.offboard_mode}")
    return Check(name, FAIL, "the autopilot says it does not take SET_POSITION_TARGET_LOCAL_NED",
                 "a firmware built with offboard/guided control")


def _failsafes(params: ParamReader, prof: AutopilotProfile) -> list[Check]:
    def v(name: str) -> float | None:
        got = params.value(name, prof)
        return got if got is not None or name not in PARAM_ALIASES else params.value(PARAM_ALIASES[name], prof)

    missing = [n for n in params.values if v(n) is None and n not in PARAM_ALIASES.values()]
    out = []
    if prof.name == "px4":
        loss_t, act = v("COM_OF_LOSS_T"), v("COM_OBL_RC_ACT")
        if loss_t is not None and act is not None:
            out.append(Check("companion link loss", PASS, f"no setpoint for COM_OF_LOSS_T={loss_t:g} s: COM_OBL_RC_ACT="
                                                          f"{act:g} ({PX4_OFFBOARD_LOSS_ACTIONS.get(int(act), '?')})"))
        dll, dll_t = v("NAV_DLL_ACT"), v("COM_DL_LOSS_T")
        if dll is not None:
            out.append(Check("GCS link loss", PASS if dll else FAIL,
                             f"NAV_DLL_ACT={dll:g} ({PX4_DLL_ACTIONS.get(int(dll), '?')})" +
                             (f", after COM_DL_LOSS_T={dll_t:g} s" if dll_t is not None else ""),
                             "" if dll else "set NAV_DLL_ACT=2 (Return) or 3 (Land), and COM_DL_LOSS_T"))
    else:
        guid = v("GUID_TIMEOUT")
        if guid is not None:
            out.append(Check("companion link loss", PASS, f"no setpoint for GUID_TIMEOUT={guid:g} s: stops and holds in GUIDED"))
        fs, fs_t, gcs = v("FS_GCS_ENABLE"), v("FS_GCS_TIMEOUT"), v("MAV_GCS_SYSID")
        if fs is not None:
            found = f"FS_GCS_ENABLE={fs:g} ({ARDUPILOT_FS_GCS.get(int(fs), '?')})" + (
                f", after FS_GCS_TIMEOUT={fs_t:g} s" if fs_t is not None else "") + (
                f", heartbeats of MAV_GCS_SYSID={gcs:g}" if gcs is not None else "")
            out.append(Check("GCS link loss", PASS if fs else FAIL, found,
                             "" if fs else "set FS_GCS_ENABLE=1 (RTL) or 5 (Land), and FS_GCS_TIMEOUT"))
    if missing:
        out.append(Check("parameters", WARN, f"no answer for {', '.join(missing)}", "PARAM_REQUEST_READ unanswered"))
    return out


def print_checks(checks: list[Check], file: Any = None) -> None:
    from rich.console import Console
    from rich.table import Table

    console = Console(file=file, width=None if file is None or getattr(file, "isatty", lambda: False)() else 200)
    style = {PASS: "green", WARN: "yellow", FAIL: "bold red"}
    t = Table(title="mrswarm preflight", show_lines=False)
    for col in ("check", "result", "found", "fix"):
        t.add_column(col, overflow="fold")
    for ch in checks:
        t.add_row(ch.name, f"[{style[ch.result]}]{ch.result}[/]", ch.found, ch.fix)
    console.print(t)
    fails = [ch.name for ch in checks if ch.result == FAIL]
    console.print("[bold red]not ready[/]: " + ", ".join(fails) if fails else "[green]ready[/]: nothing fails")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="mrswarm preflight",
                                 description="Check a flight controller for what the swarm agent needs (docs/fcu.md).")
    ap.add_argument("--fcu", required=True, metavar="URL",
                    help="the FCU link, as `mrswarm agent --fcu` takes it: udpin:127.0.0.1:14540, udpout:HOST:PORT, "
                         "serial:/dev/ttyACM0:921600, tcp:HOST:PORT")
    ap.add_argument("--fcu-bind", default=None, metavar="ADDR", help="local address of a UDP link (default: loopback)")
    ap.add_argument("--set-streams", action="store_true",
                    help="ask for the streams the agent needs, as the agent does at start-up (not stored in the autopilot)")
    ap.add_argument("--sysid", type=int, default=250, help="MAVLink system id of this check (default 250)")
    ap.add_argument("--timeout", type=float, default=10.0, help="s to wait for the first heartbeat (default 10)")
    ap.add_argument("--listen", type=float, default=8.0, help="s to listen after it (default 8)")
    ap.add_argument("--json", action="store_true", help="the checks as JSON, not a table")
    args = ap.parse_args(argv)
    if not 1 <= args.sysid <= 255:
        ap.error("--sysid: 1..255")
    if not 0 < args.timeout <= 600 or not 0 < args.listen <= 600:
        ap.error("--timeout and --listen: more than 0, at most 600 s")
    try:
        checks = run_preflight(args.fcu, sysid=args.sysid, set_streams=args.set_streams, timeout=args.timeout,
                               listen=args.listen, bind=args.fcu_bind)
    except (ValueError, LinkOpenError) as exc:
        ap.error(f"--fcu {args.fcu}: {exc}")
    except KeyboardInterrupt:
        return 130
    if args.json:
        print(json.dumps({"ok": not any(ch.result == FAIL for ch in checks), "checks": [asdict(ch) for ch in checks]},
                         indent=1))
    else:
        print_checks(checks)
    return 1 if any(ch.result == FAIL for ch in checks) else 0


if __name__ == "__main__":
    sys.exit(main())
