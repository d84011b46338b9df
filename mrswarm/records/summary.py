"""The records the runner keeps in a run folder: ``run.json`` (:class:`RunInfo`) and ``summary.json`` (:class:`RunSummary`).

One typed tree per file, so every key of ``summary.json`` is declared here once, with its
unit. Units are in the names: ``_m`` metres, ``_s`` seconds, ``_ms`` milliseconds; ``*_wall``
is a Unix wall-clock time in seconds; a ``*_s`` time is measured from the mission start (the
runner's ``start`` command), negative before it. A section that does not apply to a run
(``coverage`` for a goto mission, ``goals`` for a coverage mission, ``netem`` without a netem
configuration, ``error`` when nothing went wrong) is left out of the JSON rather than written
as ``null`` (:data:`msgspec.UNSET`); ``aborted`` is always there, ``null`` unless the runner gave up.

Both files are written atomically (temporary file, fsync, rename): a reader never sees half a
file, even if the runner is killed while writing.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import msgspec
import numpy as np
from msgspec import UNSET, Struct, UnsetType

from groundfloor.files import write_atomic
from mrswarm.records.world_summary import WorldSummary

# ---- run.json ---------------------------------------------------------------------------------

SERVICES = ("discovery", "router", "recorder")  # the run's own services, by their process names
RECORDER = "recorder"


def uav_of(name: str) -> int | None:
    """The UAV id of a process name (``uav7`` -> 7), None for a service."""
    return int(name[3:]) if name.startswith("uav") and name[3:].isdigit() else None


class ProcessEvent(Struct):
    """Something that happened to one of the run's processes (mrswarm/run/supervisor.py)."""

    t: float  # wall
    name: str  # uav3, router, discovery
    event: str  # exited, restarted, restart_failed
    exit_code: int | None = None  # of an exited process: negative = killed by that signal
    signal: str | None = None  # SIGKILL, SIGSEGV, ... when a signal ended it
    last_pose: list[float] | None = None  # x, y, z (m) of a UAV's last pose the runner received
    detail: str = ""
    error: str = ""  # a failed process's last error, from its log (mrswarm.run.supervisor.last_error)
    recorded_until: float | None = None  # "resumed" (the flight recorder): its previous file holds the records up to then
    duration_s: float | None = None  # "stalled": how long no pose of the UAV came while its process ran (from ``t``)


class FaultRecord(Struct):
    """One fault of the scenario's ``faults:`` schedule, as injected and as the runner saw the swarm react."""

    index: int  # position in the scenario's faults list
    kind: str
    at_s: float  # planned, s after the mission start
    targets: list[int] = []  # UAV ids (empty for the discovery server and the edge router)
    args: dict[str, Any] = {}
    injected: float | None = None  # wall; None: never injected (the run ended first)
    ends: float | None = None  # wall time the fault ends by itself (its duration); None: instantaneous
    ok: bool = False  # injected as planned (signal sent, fault acknowledged, netem change applied)
    detail: str = ""
    detected: float | None = None  # wall: the symptom the runner watches for appeared
    recovered: float | None = None  # wall: the swarm is back to normal


class RunInfo(Struct):
    """What the runner did, written when it stops (``run.json``); the analysis reads it back."""

    scenario: str
    started: float  # wall
    interrupted: bool = False  # Ctrl-C or SIGTERM
    aborted: str | None = None  # why the runner gave up (a UAV silent or refusing a command, a process died)
    pids: dict[str, int] = {}  # process (or container's main process) per name: "uav3", "router", "discovery", "pool1"
    pools: dict[str, list[int]] = {}  # pool process -> the virtual UAVs it hosts (fleet.pool > 1)
    mission_start: float | None = None  # wall time of the "start" command; None if the mission never started
    # time: lockstep: how the simulated clock ran (ticks, sim_s, wall_s, speedup, waiting_s...); the run's times
    # (mission_start, takeoff_sent, the UAVs' records) are then simulated time
    lockstep: dict[str, Any] | None = None
    all_done_at: float | None = None  # s after mission_start at which every UAV was done (if before the duration)
    # the takeoff: command sent (wall), every UAV acknowledged (s after it), every UAV airborne (s after it), sends
    takeoff_sent: float | None = None
    takeoff_acked_s: float | None = None
    all_airborne_s: float | None = None
    takeoff_sends: int = 0
    takeoff_by_state: int = 0  # UAVs whose state showed the takeoff before their acknowledgement arrived
    late: list[LateUav] = []  # UAVs the run went on without at a stage, and sent the command again (mrswarm/run/experiment.py)
    exit_codes: dict[str, int | None] = {}
    stopping: float | None = None  # wall: the runner began stopping every process
    stopped: float | None = None  # wall: ... and every process had stopped
    stop_signals: list[str] = []  # SIGINT, SIGTERM, SIGHUP received by the runner, in order
    events: list[ProcessEvent] = []  # processes that exited during the run, and restarts
    faults: list[FaultRecord] = []  # the scenario's fault schedule as it went
    write_errors: list[str] = []  # runner files that could not be written (a full or read-only disk)
    security: str | None = None  # network.security.mode: "mtls" or "off" (None: a run from before it existed)
    # the UAVs' MAVLink routers: "signed", "telemetry-only", "unsigned-allowed" or "off" (no routers); None: an older run
    mavlink: str | None = None
    recording_files: list[str] = []  # the flight recording's files, in order (run.mcap, run-2.mcap after a restart, ...)
    recording_unwritten: int = 0  # records of the flight recording a full disk took none of

    @classmethod
    def load(cls, path: Path, scenario: str) -> RunInfo:
        """Read ``run.json``; a folder without one (runner killed hard) gives an empty record."""
        try:
            data = path.read_bytes()
        except FileNotFoundError:
            return cls(scenario=scenario, started=0.0)
        try:
            return msgspec.json.decode(data, type=cls)
        except msgspec.DecodeError as exc:
            raise ValueError(f"{path}: {exc}") from None

    def write(self, path: Path) -> None:
        write_json_atomic(path, self)


# ---- summary.json -----------------------------------------------------------------------------


class CollisionPair(Struct):
    pair: list[int]  # the two UAV ids
    onsets: int  # times their distance fell below the collision distance
    min: float  # closest distance between them, m


class Separation(Struct):
    """Minimum 3-D distance between airborne UAVs, from their own FCU positions (10 Hz grid)."""

    min_m: float | None  # over the whole recording (takeoff included); None with fewer than two airborne UAVs
    min_pair: list[int] | None
    min_at_s: float | None
    min_during_mission_m: float | None
    safety_distance_m: float
    time_below_safety_s: float  # during the mission
    collision_distance_m: float
    collisions: int  # onsets of a pair closer than collision_distance_m
    collision_pairs: list[CollisionPair]


class Coverage(Struct):
    """Share of the mission area's cells seen by a UAV working on its mission (coverage missions)."""

    final: float  # fraction 0..1 at the end of the mission
    time_to_50_s: float | None
    time_to_90_s: float | None
    curve: list[tuple[float, float]]  # (s since mission start, fraction), 1 per second
    sensor_radius_m: float
    strategy: str


class Goal(Struct):
    reached: bool  # came within 2 m (horizontally) of its goal
    final_distance_m: float | None
    reached_at_wall: float | None = None


class Encounter(Struct):
    """Where two UAVs flying at each other met: the midpoint at their closest approach (goto, 2 UAVs)."""

    time_wall: float
    separation_m: float
    meeting_point: list[float]  # x east, y north, m
    distance_from_start_m: dict[str, float]  # per UAV id


class Rtf(Struct):
    """Real-time factor per UAV over the mission: simulated seconds per wall second."""

    per_uav: dict[str, float | None]
    mean: float | None
    min: float | None


class PoseAge(Struct):
    """A pose age merged over every UAV, ms: transport (the sender's stamp to the arrival in the
    receiving process) or at use (arrival to the controller's first use)."""

    p50: float | None
    p99: float | None
    mean: float | None
    max: float | None
    n: int  # poses


class LinkAge(Struct):
    """The transport age of one link, ms."""

    link: str  # "<sender>-><receiver>"
    p50: float | None
    p99: float | None
    max: float | None
    n: int


class LinkAges(Struct):
    """How the links compare: per-link transport ages summarised; every link is in ``csv``."""

    links: int
    p50_median_ms: float | None  # median over the links of each link's p50
    p99_median_ms: float | None
    p99_max_ms: float | None  # the worst link's p99
    worst: list[LinkAge]  # the links with the highest p99 (at most 5)
    csv: str | UnsetType = UNSET  # transport_links.csv: link, n, p50_ms, p99_ms, max_ms


class Delay(Struct):
    """Delay the netem shim added to delivered messages, ms."""

    mean: float | None
    p50: float | None
    p99: float | None
    max: float | None


class NetemConfigUse(Struct):
    config: str  # the configuration's description
    uavs: list[int]


class NetemChange(Struct):
    """One configuration change and the UAVs that applied it."""

    id: int | None  # message id of a ``mrswarm netem set`` (None for the scenario's configuration)
    source: str | None
    preset: str | None
    config: str
    t_sent: float | None  # wall, when published
    uavs: int
    applied_first: float  # wall
    applied_last: float  # wall
    latency_max_s: float | UnsetType = UNSET  # published -> applied on the last UAV (only when t_sent is known)


class NetemTotals(Struct):
    sent: int
    delivered: int
    duplicated: int
    reordered: int
    jumps: int
    dropped: int
    loss: float  # dropped / (sent + duplicated)
    delay_ms: Delay


class NetemClass(Struct):
    links: int
    sent: int
    delivered: int
    duplicated: int
    reordered: int
    jumps: int
    dropped: int
    dropped_by: dict[str, int]  # reason -> messages
    loss: float
    delay_ms: Delay


class NetemLink(Struct):
    link: str  # "<sender>-><receiver>"
    cls: str = msgspec.field(name="class")  # v2v, v2edge, ... or "unimpaired"
    sent: int
    delivered: int
    duplicated: int
    reordered: int
    jumps: int
    dropped: int
    dropped_by: dict[str, int]  # reason -> messages
    delay_ms: Delay


class Netem(Struct):
    """The netem shim's statistics (docs/netem.md)."""

    configs: list[NetemConfigUse]
    changes: list[NetemChange]
    total: NetemTotals
    classes: dict[str, NetemClass]
    links: list[NetemLink]


class PoseAgeOverTime(Struct):
    """Per second since the mission start: medians over UAVs (transport age p50, age at use p50,
    age of information) and the max AoI, ms."""

    t_s: list[float]
    transport_p50_ms: list[float | None]
    use_p50_ms: list[float | None]
    aoi_mean_ms: list[float | None]
    aoi_max_ms: list[float | None]
    plot: str | UnsetType = UNSET  # pose_age.png
    plot_error: str | UnsetType = UNSET


class Takeoff(Struct):
    """The runner's takeoff command, s after it was first sent."""

    acked_s: float | None  # every UAV acknowledged it, or showed it in its state (None: not all did)
    all_airborne_s: float | None  # every UAV hovered at its altitude (None: not all did)
    sends: int  # times it was sent (re-sent to the UAVs that had not acknowledged)
    by_state: int = 0  # UAVs whose state showed the takeoff before their acknowledgement arrived
    late: dict[str, str] = {}  # UAV id -> where it was late: the run went on without it, and it joined when ready


class LateUav(Struct):
    """A virtual UAV that was not ready, airborne or acknowledging when the others were: the run went
    on without it (at most LATE_MAX_FRACTION of the fleet), and the runner sent it the command again."""

    uav: int
    stage: str  # ready, takeoff, hover, start: what it was late for
    t: float  # wall time the run went on without it


class Network(Struct):
    transport_age_ms: PoseAge  # sender's stamp -> arrival in the receiving process, every link
    use_age_ms: PoseAge  # arrival -> first use by the controller
    messages_sent: dict[str, int]  # per message kind, summed over UAVs
    messages_received: dict[str, int]
    messages_rejected: dict[str, int]  # per reason
    pose_loss: float  # fraction of neighbours' poses lost (sequence gaps)
    # ages below zero, left out of the histograms: a receiver whose clock is behind its sender's
    # (two hosts); never on one host
    negative_ages: dict[str, int] = {}
    transport_age_links: LinkAges | UnsetType = UNSET
    netem: Netem | UnsetType = UNSET
    pose_age_over_time: PoseAgeOverTime | UnsetType = UNSET
    pose_age_over_time_error: str | UnsetType = UNSET


class LostUav(Struct):
    """A UAV process that exited before the end of the run (an event, not the end of the run)."""

    uav: int
    t_s: float  # s after the mission start
    exit_code: int | None
    signal: str | None  # what ended it, if a signal did
    last_pose: list[float] | None  # x, y, z, m, as last received by the runner
    restarted_s: float | None = None  # s after the mission start the process was started again (fleet.restart)
    injected: bool = False  # the fault schedule caused it
    error: str = ""  # its last error, from its log ("" if it logged none)


class Stall(Struct):
    """A UAV whose process ran but sent no pose for more than a second (stopped, starved: mrswarm/run/stalls.py)."""

    uav: int
    from_s: float  # its last pose before the stall, s after the mission start
    duration_s: float


class ServiceOutage(Struct):
    """The discovery server or the edge router down during the run, and its restart."""

    name: str
    down_s: float  # s after the mission start
    exit_code: int | None
    restarted_s: float | None  # None: never came back


class FaultReport(Struct):
    """One row of the per-fault table (docs/reliability.md says how each column is measured per kind)."""

    kind: str
    at_s: float  # injected, s after the mission start
    targets: list[int]
    ok: bool  # injected as planned
    detection_s: float | None  # from injection to the symptom the swarm (or runner) reacts to; None: not seen
    recovery_s: float | None  # from injection to back to normal; None: did not recover in the run
    collisions: int  # collision onsets between injection and recovery (or the end of the run)
    coverage_lost: float | None  # share of the area the affected UAVs would have swept while out of the mission
    detail: str = ""


class FailsafeEvent(Struct):
    """A companion failsafe of one UAV (uav_stack/failsafe.py): triggered, its action, cleared."""

    uav: int
    t_s: float  # s after the mission start
    failsafe: str  # swarm_link, fcu_link, position, battery
    event: str  # triggered, land, rtl, resumed, cleared, warning
    detail: str


class Incident(Struct):
    """A UAV that fell or hit the ground, or two UAVs closer than the safety distance (mrswarm/results/incidents.py):
    counted beside collisions."""

    uav: int  # below_safety_distance: the first of the pair
    kind: str  # ground_impact, uncontrolled_descent, motors_stopped_in_air, below_safety_distance
    t_s: float  # s after the mission start
    detail: str
    z_m: float | UnsetType = UNSET  # height above the origin when it began (a UAV's own incidents)
    vz_ms: float | UnsetType = UNSET  # vertical speed (up positive), m/s (a UAV's own incidents)
    pair: list[int] | UnsetType = UNSET  # below_safety_distance: the two UAVs
    min_m: float | UnsetType = UNSET  # ... their closest distance, m
    min_at_s: float | UnsetType = UNSET  # ... when, s after the mission start
    duration_s: float | UnsetType = UNSET  # ... time below the safety distance, s


class BehaviourSummary(Struct):
    """The SDK behaviours the UAVs flew (docs/sdk.md; mrswarm/results/behaviour_report.py): summed over the UAVs."""

    behaviours: list[str]  # as the scenario names them
    uavs: int
    steps: int
    step_max_ms: float  # the longest step of any UAV
    faults: dict[str, int]  # exceptions, overruns, bad_intents
    stopped: list[int]  # UAVs whose behaviour its guard stopped (they held, then landed; an incident each)
    topics: dict[str, dict[str, Any]]  # topic -> sent, send_errors, received, rejected, dropped, age_mean_ms, age_max_ms


class RecordErrors(Struct):
    """Recording errors the UAVs counted (a full or read-only disk): the flight went on, these records did not."""

    uavs: list[int]  # UAVs with at least one failed write
    errors: dict[str, int]  # errno name -> failed writes, summed
    rows_dropped: int  # trajectory or pose-age rows given up (beyond the in-memory backlog)
    files_not_written: int  # counter-file replacements that failed
    runner: list[str]  # runner files that could not be written


class RecordingGap(Struct):
    """The flight recorder down, and recording again (mrswarm/run/supervisor.py restarts it)."""

    from_s: float  # s after the mission start: its file holds the records up to then (its last flush before it died)
    to_s: float | None  # recording again, into the next file (None: not before the end of the run)
    gap_s: float | None
    cause: str  # what ended it: a signal, an exit code


class Recording(Struct):
    """The flight recording (docs/recording.md): its files, the recorder's gaps, what a full disk took none of."""

    files: list[str]
    gaps: list[RecordingGap] = []
    unwritten: int = 0


class Security(Struct):
    """How the run's network was secured, and what it refused (docs/security.md, "What is counted")."""

    mode: str  # "mtls": mutual TLS and access control on every link; "off": plain TCP
    refused_by_uavs: dict[str, int]  # summed over UAVs: tls_handshake (their listeners), non_member_link
    refused_by_router: dict[str, int]  # the edge router's: tls_handshake, non_member_link (process runtime)


class ExternalUav(Struct):
    """A UAV whose flight controller is external (a real autopilot, a SITL; docs/scenarios.md): counted like any other."""

    uav: int
    realm: str  # physical or virtual (a SITL may be flown as a virtual UAV)
    fcu: str  # its flight controller's connection string, as the scenario gives it
    agent: str  # runner: its agent ran on this machine; companion: on the UAV's companion computer
    trajectory: str  # agent: its own uav<N>.csv; recording: the poses it shared, from run.mcap; none: neither
    detail: str = ""


class Mavlink(Struct):
    """What the UAVs' MAVLink routers took from ground stations (docs/security.md, "MAVLink")."""

    mode: str  # "signed": commands signed with the key only; "telemetry-only" (no key); "unsigned-allowed"; "off"
    refused: dict[str, int]  # summed over UAVs: unsigned_refused (of which unsigned_commands_refused), bad_signature, ...
    accepted: dict[str, int]  # summed over UAVs: signed frames, unsigned_accepted, to_fcu (frames routed to the FCUs)


class RunSummary(Struct):
    """``summary.json``: the outcome of one run, computed from the files its UAVs recorded."""

    scenario: str
    run_dir: str
    uavs_planned: int
    uavs_recorded: int
    interrupted: bool  # stopped by a signal, or the runner died before writing its end (runner_lost)
    # the runner died (killed) before writing the end of run.json: its results are rebuilt from what was on disk
    runner_lost: bool = False
    interrupted_at_wall: float | UnsetType = UNSET  # the last known time of an interrupted run: its stop, else its newest record
    interrupted_at_s: float | UnsetType = UNSET  # the same, s after the mission start (left out if the mission never started)
    error: str | UnsetType = UNSET  # nothing to analyse (no trajectory recorded)
    separation: Separation | UnsetType = UNSET
    coverage: Coverage | UnsetType = UNSET
    goals: dict[str, Goal] | UnsetType = UNSET  # per UAV id
    encounter: Encounter | None | UnsetType = UNSET  # goto with 2 UAVs; None: they were never airborne together
    rtf: Rtf | UnsetType = UNSET
    takeoff: Takeoff | UnsetType = UNSET
    network: Network | UnsetType = UNSET
    world: WorldSummary | UnsetType = UNSET  # scenarios with a world section (mrswarm/records/world_summary.py)
    security: Security | UnsetType = UNSET  # left out for runs from before network.security existed
    mavlink: Mavlink | UnsetType = UNSET  # left out for runs from before the routers were locked
    processes: dict[str, int | None] = {}  # exit code per process
    duration_s: float | UnsetType = UNSET  # mission time analysed
    plot: str | UnsetType = UNSET  # <scenario>.png
    plot_error: str | UnsetType = UNSET
    aborted: str | None = None
    stop_signals: list[str] = []  # signals that stopped the runner
    incidents: list[Incident] = []
    lost_uavs: list[LostUav] = []
    stalls: list[Stall] = []  # UAVs alive but silent for more than a second
    services: list[ServiceOutage] = []
    faults: list[FaultReport] = []
    failsafes: list[FailsafeEvent] = []
    behaviour: BehaviourSummary | UnsetType = UNSET  # runs of SDK behaviours (docs/sdk.md)
    records: RecordErrors | UnsetType = UNSET  # only when some recording failed
    external_uavs: list[ExternalUav] | UnsetType = UNSET  # only with UAVs whose flight controller is external
    recording: Recording | UnsetType = UNSET  # the flight recording (runs with one)
    # why the run's records are incomplete (records lost to a full or failing disk, a recorder gap, a file not
    # written); empty when they are whole. Not empty: ``mrswarm run`` exits 1 (3 with collisions or incidents)
    degraded: list[str] = []
    # why the host could not keep up (UAV loops late, poses lost on unimpaired links): its figures measure the
    # machine, not the swarm (mrswarm/results/saturation.py). Not empty: ``mrswarm run`` exits 4
    saturated: list[str] = []
    write_error: str | UnsetType = UNSET  # summary.json itself could not be written (only in the printed summary)

    @property
    def safety_events(self) -> int:
        """Collisions plus incidents: any makes ``mrswarm run`` exit with 3."""
        sep = self.separation
        return (sep.collisions if sep else 0) + len(self.incidents)

    def to_dict(self) -> dict[str, Any]:
        """The JSON object as plain Python values (what ``json.load`` of summary.json gives)."""
        out: dict[str, Any] = msgspec.to_builtins(self, enc_hook=_numpy_scalar)
        return out

    def write(self, path: Path) -> None:
        write_json_atomic(path, self)

    @classmethod
    def load(cls, path: Path) -> RunSummary:
        return msgspec.json.decode(path.read_bytes(), type=cls)


def _numpy_scalar(o: Any) -> Any:
    """A numpy number that slipped into a record is written as the Python number it holds."""
    if isinstance(o, np.generic):
        return o.item()
    raise NotImplementedError(f"cannot write {type(o).__name__} to JSON")


def write_json_atomic(path: Path, record: Struct) -> None:
    """Write ``record`` as indented JSON to ``path``: temporary file, fsync, rename, fsync the folder."""
    data = msgspec.json.format(msgspec.json.encode(record, enc_hook=_numpy_scalar), indent=2) + b"\n"
    write_atomic(path, data, fsync=True)
