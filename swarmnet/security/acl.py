"""Zenoh access control for one swarm, generated from its roster (docs/security.md).

Every node of a secured swarm (UAVs, ground stations, the runner, the edge router) loads the
same rules: a node enforces them on what its links bring in (``ingress``) and on what it sends
out (``egress``), and Zenoh names the remote end of a link by its certificate's common name.
Zenoh's rules have no per-subject templates, so there is one subject, one ingress rule and one
egress rule per UAV (``uav-3.alpha`` may put only ``mrs/alpha/3/...``) and per pool of virtual
UAVs (``pool-1.alpha`` may put what each UAV its roster entry lists may put, and no other's), and
one subject and rule set per other role. ``default_permission`` is ``deny``: a certificate the roster does not
list (revoked, or never issued) gets nothing through.

=========  ======================================================  ===========================================
 subject    may put (ingress)                                       receives (egress)
=========  ======================================================  ===========================================
 uav-N      its pose, telemetry, state, acks, its swarm messages,   every pose, the pose feed and its near feed
            its liveliness token ``alive/uav/N``, its actuator      ``feed/near/N``, its own and the swarm's
            requests ``N/act/*``, its behaviour reports             commands, netem, its faults, the swarm's
            ``N/behaviour``                                         broadcasts and its unicasts, its sensor
                                                                    readings ``N/sense/*``, the airspace feed
                                                                    ``mrs/airspace/<swarm>/traffic``
 pool-N     what each UAV of its roster entry may put, and its      what each of those UAVs receives, the
            answers to the lock-step clock ``clock/done/pool-N``    pool's near feed ``feed/near/pool-N`` and
                                                                    the lock-step clock's steps ``clock/step``
 gcs-N      commands (``cmd``, ``<uav>/cmd``), ``alive/gcs/*``       everything of the swarm
 ctl        commands, ``netem/set``, ``<uav>/fault``,               everything of the swarm
            ``alive/observer/*``, the clock's steps ``clock/step``
 edge       everything of the swarm (it forwards what others put),  everything of the swarm
            the airspace feed (the world service speaks as edge)
=========  ======================================================  ===========================================

"Everything of the swarm" is ``mrs/<swarm>/**`` and the swarm's airspace feed, which lies
outside that tree (docs/world.md): only the edge puts it, only the swarm's members receive it.

Declarations (subscribers, liveliness subscribers and queries) are allowed both ways for every
member: Zenoh routes data only towards declared interest, so they must cross every link.

What the rules cannot say, :mod:`swarmnet.messages` checks on every sample: the payload names
the UAV its key names (a pose, state, ack, a swarm message's sender), also inside edge-feed
batches.
"""

from __future__ import annotations

from typing import Any

from swarmnet.keyspace import SwarmKeys
from swarmnet.security.roster import Roster

EVERY_MESSAGE = ("put", "delete", "declare_subscriber", "query", "reply", "declare_queryable",
                 "liveliness_token", "liveliness_query", "declare_liveliness_subscriber")
DECLARATIONS = ("declare_subscriber", "declare_liveliness_subscriber", "liveliness_query")
BOTH = ("ingress", "egress")


def _rule(rule_id: str, messages: tuple[str, ...], flows: tuple[str, ...], key_exprs: list[str]) -> dict[str, Any]:
    return {"id": rule_id, "messages": list(messages), "flows": list(flows), "permission": "allow", "key_exprs": key_exprs}


def uav_puts(keys: SwarmKeys, uav: int) -> list[str]:
    """What UAV ``uav`` may publish: only under its own id."""
    return [keys.pose(uav), keys.telemetry(uav), keys.state(uav), keys.ack(uav), keys.broadcast(uav, "**"),
            keys.unicast(uav, "*", "**"), keys.alive("uav", uav), keys.act(uav, "*"), keys.behaviour(uav)]


def uav_receives(keys: SwarmKeys, uav: int) -> list[str]:
    """What is sent to UAV ``uav``: what its node subscribes to, nothing else (not others' commands)."""
    return [keys.all_poses, keys.pose_feed, keys.near_feed(uav), keys.swarm_cmd, keys.cmd(uav), keys.netem_set, keys.fault(uav),
            keys.all_broadcast, keys.all_unicast(uav), keys.all_alive, keys.all_senses(uav), keys.traffic]


def access_control(roster: Roster) -> dict[str, Any]:
    """The ``access_control`` section of a Zenoh configuration for the roster's swarm."""
    keys = SwarmKeys(roster.swarm)
    everything = [f"{keys.prefix}/**", keys.traffic]  # the swarm's tree, and the airspace feed into it (docs/world.md)
    rules = [_rule("declare", DECLARATIONS, BOTH, everything),
             _rule("observe", ("put", "liveliness_token"), ("egress",), everything),
             _rule("forward", EVERY_MESSAGE, BOTH, everything)]
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []
    staff: dict[str, list[str]] = {"gcs": [], "ctl": [], "edge": []}  # CNs per non-UAV role
    for name in roster.names():
        if name.role not in ("uav", "pool"):
            staff[name.role].append(name.cn)
            continue
        sid = name.short
        uavs = roster.speaks_for(name.cn) if name.role == "pool" else (name.node,)
        puts = [k for u in uavs for k in uav_puts(keys, u)]
        receives = [k for u in uavs for k in uav_receives(keys, u)]
        if name.role == "pool":  # the edge's one near batch for all its UAVs (swarmnet/interest.py)
            receives += [keys.pool_near_feed(name.node), keys.clock_step]  # and lock-step time (swarmnet/lockstep.py)
            puts.append(keys.clock_done(name.node))
        rules.append(_rule(f"{sid}.in", ("put", "liveliness_token"), ("ingress",), puts))
        rules.append(_rule(f"{sid}.out", ("put", "liveliness_token"), ("egress",), list(dict.fromkeys(receives))))
        subjects.append({"id": sid, "cert_common_names": [name.cn]})
        policies.append({"id": sid, "rules": ["declare", f"{sid}.in", f"{sid}.out"], "subjects": [sid]})
    command = [keys.swarm_cmd, keys.cmd("*")]
    rules.append(_rule("gcs.in", ("put", "liveliness_token"), ("ingress",), [*command, keys.alive("gcs", "*")]))
    rules.append(_rule("ctl.in", ("put", "liveliness_token"), ("ingress",),
                       [*command, keys.netem_set, keys.fault("*"), keys.alive("observer", "*"), keys.clock_step,
                                      keys.clock_world_step]))
    grants = {"gcs": ["declare", "observe", "gcs.in"], "ctl": ["declare", "observe", "ctl.in"], "edge": ["forward"]}
    for role, cns in staff.items():
        if cns:
            subjects.append({"id": role, "cert_common_names": sorted(cns)})
            policies.append({"id": role, "rules": grants[role], "subjects": [role]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects, "policies": policies}


def member_names(roster: Roster) -> frozenset[str]:
    """The CNs the rules grant anything to (for counting links of anyone else)."""
    return frozenset(n.cn for n in roster.names())
