"""Random MAVLink datagrams, as a fuzzer aimed at one UAV sends them (tests/test_mavlink_attack.py).

Mostly well-formed frames with good CRCs, so that a parser takes them for real: messages of any id
of the dialect with random payloads, from the ids a ground station, the FCU or the companion use;
commands that would disarm, land, move, reboot or reconfigure the UAV, addressed to it; frames of
ids no dialect defines; frames signed with a wrong key; and bytes that are no frame at all, or a
frame with a flipped bit or cut short.
"""

from __future__ import annotations

import hashlib
import random
import struct

from uav_stack.mav import mavlink as M

UNKNOWN_IDS = (59000, 59001, 0xFFFF00, 0xFFFFFF)  # ids no dialect defines
# (command, params) that would take the UAV away from its mission if they were obeyed
DANGEROUS_COMMANDS = (
    (M.MAV_CMD_COMPONENT_ARM_DISARM, (0, 21196)),  # force disarm, in the air
    (M.MAV_CMD_DO_SET_MODE, (1, 9)),  # ArduPilot LAND
    (M.MAV_CMD_DO_SET_MODE, (1, 6)),  # ArduPilot RTL
    (M.MAV_CMD_NAV_LAND, ()),
    (M.MAV_CMD_NAV_RETURN_TO_LAUNCH, ()),
    (M.MAV_CMD_DO_FLIGHTTERMINATION, (1,)),
    (M.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, (1,)),
    (M.MAV_CMD_DO_CHANGE_SPEED, (1, 0.1)),
)


def _frame_v2(msg_id: int, payload: bytes, src: tuple[int, int], seq: int, crc_extra: int, signed_with: bytes | None) -> bytes:
    header = bytes([M.PROTOCOL_MARKER_V2, len(payload), M.MAVLINK_IFLAG_SIGNED if signed_with else 0, 0, seq & 0xFF,
                    src[0], src[1], msg_id & 0xFF, msg_id >> 8 & 0xFF, msg_id >> 16 & 0xFF])
    crc = M.x25crc(header[1:] + payload)
    crc.accumulate(bytes([crc_extra]))
    frame = header + payload + struct.pack("<H", crc.crc)
    if signed_with:
        block = bytes([0]) + struct.pack("<Q", random.getrandbits(47))[:6]
        frame += block + hashlib.sha256(signed_with + frame + block).digest()[:6]
    return frame


def _frame_v1(msg_id: int, payload: bytes, src: tuple[int, int], seq: int, crc_extra: int) -> bytes:
    header = bytes([M.PROTOCOL_MARKER_V1, len(payload), seq & 0xFF, src[0], src[1], msg_id])
    crc = M.x25crc(header[1:] + payload)
    crc.accumulate(bytes([crc_extra]))
    return header + payload + struct.pack("<H", crc.crc)


class Fuzzer:
    """Random datagrams aimed at the UAV whose FCU has system id ``sysid``."""

    def __init__(self, sysid: int, seed: int = 0):
        self.rng = random.Random(seed)
        self.sysid = sysid
        self.ids = sorted(M.mavlink_map)
        self.gcs = M.MAVLink(None, 255, 190)
        self.seq = 0
        # the ids a forger would pose as: ground stations, the FCU itself, the companion, anyone
        self.sources = [(255, 190), (sysid, 1), (sysid, M.MAV_COMP_ID_ONBOARD_COMPUTER), (245, 190), (1, 1)]

    def _src(self) -> tuple[int, int]:
        r = self.rng
        return r.choice(self.sources) if r.random() < 0.8 else (r.randrange(256), r.randrange(256))

    def dangerous(self) -> bytes:
        """A command or message that would move, stop or reconfigure the UAV, addressed to it."""
        r = self.rng
        t = self.sysid
        kind = r.randrange(6)
        if kind <= 2:
            cmd, params = r.choice(DANGEROUS_COMMANDS)
            p = [*params, *[0.0] * (7 - len(params))]
            if kind == 2:
                msg = M.MAVLink_command_int_message(t, 1, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, cmd, 0, 0, *p[:4],
                                                    int(p[4]), int(p[5]), p[6])
            else:
                msg = M.MAVLink_command_long_message(t, 1, cmd, 0, *p)
        elif kind == 3:
            msg = M.MAVLink_set_mode_message(t, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, r.choice((9, 6, 5, 0)))
        elif kind == 4:
            msg = M.MAVLink_set_position_target_local_ned_message(0, t, 1, M.MAV_FRAME_LOCAL_NED, 0b110111000111, 0, 0, 0,
                                                                  r.uniform(-10, 10), r.uniform(-10, 10), 5.0, 0, 0, 0, 0, 0)
        else:
            msg = M.MAVLink_param_set_message(t, 1, r.choice((b"FENCE_ENABLE", b"DISARM_DELAY", b"WPNAV_SPEED")),
                                              r.uniform(0, 100), M.MAV_PARAM_TYPE_REAL32)
        self.gcs.srcSystem, self.gcs.srcComponent = self._src()
        return bytes(msg.pack(self.gcs))

    def frame(self) -> bytes:
        r = self.rng
        self.seq += 1
        kind = r.random()
        if kind < 0.3:
            return self.dangerous()
        if kind < 0.4:  # an id no dialect defines: nobody can check its CRC
            payload = r.randbytes(r.randrange(1, 64))
            return _frame_v2(r.choice(UNKNOWN_IDS), payload, self._src(), self.seq, r.randrange(256),
                             r.randbytes(32) if r.random() < 0.5 else None)
        msg_id = r.choice(self.ids)
        cls = M.mavlink_map[msg_id]
        size = cls.unpacker.size
        if msg_id < 256 and kind < 0.5:  # MAVLink 1: never signed
            return _frame_v1(msg_id, r.randbytes(size), self._src(), self.seq, cls.crc_extra)
        wrong_key = r.randbytes(32) if kind > 0.9 else None
        return _frame_v2(msg_id, r.randbytes(r.randrange(1, size + 1)), self._src(), self.seq, cls.crc_extra, wrong_key)

    def datagram(self) -> bytes:
        r = self.rng
        if r.random() < 0.1:  # no frame at all (sometimes starting like one)
            return bytes([r.choice((0xFD, 0xFE, r.randrange(256)))]) + r.randbytes(r.randrange(0, 300))
        data = b"".join(self.frame() for _ in range(r.randrange(1, 5)))
        if r.random() < 0.1:  # a flipped bit, or cut short
            b = bytearray(data)
            if r.random() < 0.5:
                b[r.randrange(len(b))] ^= 1 << r.randrange(8)
            else:
                del b[r.randrange(1, len(b)):]
            data = bytes(b)
        return data

    def datagrams(self, n: int) -> list[bytes]:
        return [self.datagram() for _ in range(n)]


def would_command(datagrams: list[bytes], sysid: int) -> int:
    """How many of the dangerous frames in ``datagrams`` an open parser would take: COMMAND_LONG,
    COMMAND_INT and SET_MODE addressed to ``sysid`` (what made the probe's UAVs yield and land)."""
    p = M.MAVLink(None)
    p.robust_parsing = True
    n = 0
    for d in datagrams:
        for m in p.parse_buffer(d) or []:
            if m.get_type() in ("COMMAND_LONG", "COMMAND_INT", "SET_MODE") and m.target_system == sysid:
                n += 1
        p.buf, p.buf_index = bytearray(), 0
    return n
