"""Runs spread over the nodes of a Docker Swarm: one replicated job (a one-shot service) per run.

``mrswarm sweep FILE --on swarm``, with ``DOCKER_HOST`` (or the local engine) a manager of the
swarm. Each run becomes a service in ``replicated-job`` mode from the stack image (``mrswarm
deploy build``; ``--image``): one task, never restarted, that runs exactly the command line a
local run gets (:func:`mrswarm.sweep.launch.run_command`) through :mod:`mrswarm.sweep.job`, with
the process runtime inside its container: its UAV processes, discovery server and edge router
speak on the container's own loopback (the container sits on its node's default bridge: Swarm
attaches a service to no ``none`` network). Swarm
places the job on a node whose unreserved CPU and memory hold the run's need (its reservation:
the same estimate as for parallel runs on one machine, :mod:`mrswarm.sweep.capacity`), and
holds it pending until one has room; ``--parallel`` caps the jobs submitted at once (default:
the cluster's cores over a run's need).

**The campaign folder must be shared**: every node must see ``--out`` at the same path (NFS or
another shared file system; on the test cluster of ``mrswarm deploy cluster``, every node sees
the host's file system). The job bind-mounts it and writes the run folder there, as a local run
would; the sweep reads it as for a local run. A job whose result the sweep cannot see (the
folder not shared with its node) is reported as such.

Stopping: the sweep appends the stop signal to each running job's stop file in the slot
(``stop-<n>``, :mod:`mrswarm.sweep.job`), and the job's wrapper sends it to the run, which stops
its UAVs and writes an interrupted summary (flown again by the next sweep); the service is
removed once its run has ended. (Removing a job's service does not stop its running task.)

What is not measured here: the load of the nodes. Swarm schedules by reservations, so a node
running other work beside the campaign's jobs would slow its runs; keep the nodes for the
campaign. A scenario with an external flight controller is refused (its autopilot is reachable
from one machine only).
"""

from __future__ import annotations

import hashlib
import os
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from deploy.dockerutil import L_ROLE, L_RUN, DeployError
from mrswarm.scenario import Scenario
from mrswarm.sweep.campaign import Slot
from mrswarm.sweep.capacity import Need
from mrswarm.sweep.job import read_result
from mrswarm.sweep.launch import RunOptions, run_command, tail_line
from mrswarm.sweep.slots import Attempt, SlotRecord, new_attempt, run_folders, write_record

STOP_GRACE_S = 60.0  # SIGTERM -> SIGKILL of a job's container stopped by Docker (a node drained, docker stop)
STOPPED_WAIT_S = 90.0  # after a stop signal, how long a job's run may take to end before the sweep gives up on it
UNSEEN_WAIT_S = 10.0  # a job Swarm says is complete whose result does not show: the folder is not shared
SCENARIO_COPY = "scenario-file.yaml"  # the scenario file, copied into the campaign folder (the jobs read it there)
ROLE = "sweep-run"
FAILED_STATES = ("failed", "rejected", "orphaned")


def scenario_files_problem(scn: Scenario) -> str:
    """A file the scenario names on this machine, which a job on another node cannot read ("" if none)."""
    sec = scn.network.secured
    if sec.keys is not None:
        return f"network.security.keys: {sec.keys}: a key directory on this machine; runs on a swarm make their own keys"
    if scn.gcs.signing is not None and scn.gcs.signing.key_file is not None:
        return f"gcs.signing.key_file: {scn.gcs.signing.key_file}: a file on this machine"
    if scn.runtime == "docker":
        return "runtime: docker: a run on a swarm node flies its UAVs as processes in its own container"
    return ""


def service_kwargs(*, image: str, argv: list[str], out: Path, name: str, run_label: str, need: Need, uid: int,
                   gid: int) -> dict[str, Any]:
    """The arguments of ``client.services.create`` for one run's job."""
    from docker.types import Mount, Resources, RestartPolicy, ServiceMode

    folder = str(out.resolve())
    return {
        "image": image,
        "command": argv,
        "name": name,
        "labels": {L_RUN: run_label, L_ROLE: ROLE},
        "container_labels": {L_RUN: run_label, L_ROLE: ROLE},
        "mode": ServiceMode("replicated-job"),
        "restart_policy": RestartPolicy(condition="none"),
        "resources": Resources(cpu_reservation=int(need.cores * 1e9), mem_reservation=int(need.memory_mb * 2**20)),
        "mounts": [Mount(target=folder, source=folder, type="bind")],
        "workdir": folder,
        "user": f"{uid}:{gid}",
        "env": ["HOME=/tmp", "COLUMNS=120", "MPLCONFIGDIR=/tmp/matplotlib"],
        "hostname": "{{.Node.Hostname}}",
        "init": True,
        "stop_grace_period": int(STOP_GRACE_S * 1e9),
    }


@dataclass
class SwarmJob:
    """A run flying as a Swarm job."""

    slot: Slot
    folder: Path
    record: SlotRecord
    attempt: Attempt
    log_path: Path
    result_path: Path
    stop_path: Path
    service: Any
    client: Any
    before: set[str]
    busy: list[float] = field(default_factory=list)  # not measured on a remote node
    t0: float = field(default_factory=time.monotonic)
    stopped_at: float | None = None  # the first stop signal
    done_at: float | None = None  # Swarm said the task is complete

    @property
    def elapsed(self) -> float:
        return time.monotonic() - self.t0

    def last_line(self) -> str:
        r = read_result(self.result_path)
        where = f"[{r.node}] " if r is not None else "[waiting for a node] "
        return where + tail_line(self.log_path)

    def signal(self, sig: int) -> None:
        """A stop signal for the run, through its stop file (its wrapper sends it to the run)."""
        from mrswarm.sweep.job import ask_stop

        self.stopped_at = self.stopped_at or time.monotonic()
        try:
            ask_stop(self.stop_path, sig)
        except OSError:
            pass

    def _remove(self) -> None:
        try:
            self.service.remove()
        except Exception:  # noqa: BLE001 - gone already
            pass

    def _task(self) -> tuple[str, str]:
        """The job's task: its state and error ("" when there is none yet)."""
        try:
            tasks = self.service.tasks()
        except Exception:  # noqa: BLE001 - the service is gone (removed)
            return "", ""
        if not tasks:
            return "", ""
        st = tasks[-1].get("Status", {})
        return str(st.get("State", "")), str(st.get("Err", ""))

    def poll(self) -> bool:
        r = read_result(self.result_path)
        if r is not None and r.ended is not None:
            self._finish(r.exit_code, r.wall_s, r.cpu_s, f"swarm:{r.node}")
            self._remove()
            return True
        state, err = self._task()
        if self.stopped_at is not None and (not state or time.monotonic() - self.stopped_at > STOPPED_WAIT_S):
            if state and state not in ("complete", *FAILED_STATES):
                self._say(f"the run did not end within {STOPPED_WAIT_S:g} s of the stop; its job is left in the swarm")
            else:
                self._remove()
            self._finish(None, None, None, f"swarm:{r.node}" if r else "swarm")
            return True
        if state in FAILED_STATES:
            self._say(f"the job's task {state}: {err or 'no reason given'}")
            self._finish(None, None, None, f"swarm:{r.node}" if r else "swarm")
            self._remove()
            return True
        if state == "complete":
            self.done_at = self.done_at or time.monotonic()
            if time.monotonic() - self.done_at > UNSEEN_WAIT_S:
                self._say(f"the job completed, but its result is not in {self.folder}: is the campaign folder shared "
                          "with every node, at the same path?")
                self._finish(None, None, None, "swarm")
                self._remove()
                return True
        return False

    def _say(self, text: str) -> None:
        with open(self.log_path, "a") as f:
            f.write(f"mrswarm sweep: {text}\n")

    def _finish(self, code: int | None, wall: float | None, cpu: float | None, where: str) -> None:
        a = self.attempt
        a.ended = time.time()
        a.exit_code = code
        a.wall_s = wall
        a.cpu_s = cpu
        a.where = where
        made = [d for d in run_folders(self.folder) if d.name not in self.before]
        a.run_dir = made[-1].name if made else None
        write_record(self.folder, self.record)


class SwarmJobs:
    """The launcher of ``--on swarm``: every run a replicated job of the swarm this engine manages."""

    where = "the swarm"

    def __init__(self, out: Path, scenario: Path, image: str, opts: RunOptions, client: Any | None = None) -> None:
        from deploy.dockerutil import client as docker_client

        self.out = out
        self.image = image
        self.opts = opts
        self.client = client or docker_client()
        info = self.client.info()
        sw = info.get("Swarm") or {}
        if sw.get("LocalNodeState") != "active" or not sw.get("ControlAvailable"):
            raise DeployError("--on swarm: this docker engine is not a manager of a swarm (DOCKER_HOST names a manager; "
                              "`docker swarm init`, or `mrswarm deploy cluster up` for a test cluster)")
        nodes = [n.attrs for n in self.client.nodes.list()]
        self.nodes = {n["Description"]["Hostname"]: n["Description"]["Resources"] for n in nodes
                      if n["Status"]["State"] == "ready" and n["Spec"].get("Availability") == "active"}
        if not self.nodes:
            raise DeployError("--on swarm: no node of the swarm is ready and active")
        try:
            self.client.images.get(image)
        except Exception:  # noqa: BLE001 - docker.errors.ImageNotFound, or the engine's own error
            raise DeployError(f"--on swarm: no image {image} on the manager: `mrswarm deploy build` (every node needs it: "
                              "no registry, `docker save | docker load` on each)") from None
        self.label = "sweep-" + hashlib.sha256(str(out.resolve()).encode()).hexdigest()[:10]
        out.mkdir(parents=True, exist_ok=True)
        self.scenario = out / SCENARIO_COPY
        if scenario.resolve() != self.scenario.resolve():
            shutil.copyfile(scenario, self.scenario)

    @property
    def cores(self) -> float:
        return sum(r.get("NanoCPUs", 0) for r in self.nodes.values()) / 1e9

    def largest_node(self) -> tuple[str, float, float]:
        """The node with the most CPUs: its name, cores and memory (MB)."""
        name, r = max(self.nodes.items(), key=lambda kv: kv[1].get("NanoCPUs", 0))
        return name, r.get("NanoCPUs", 0) / 1e9, r.get("MemoryBytes", 0) / 2**20

    def problem(self, scn: Scenario, need: Need) -> str:
        """Why runs of ``scn`` cannot fly on this swarm ("" if they can)."""
        files = scenario_files_problem(scn)
        if files:
            return files
        if scn.external_uavs():
            u = scn.external_uavs()[0]
            return f"UAV {u.id}'s flight controller is external ({u.fcu}): its runs fly on the machine it is wired to"
        name, cores, mb = self.largest_node()
        if need.cores > cores or need.memory_mb > mb:
            return (f"a run needs about {need.cores:.1f} cores and {need.memory_mb:,.0f} MB; the largest node ({name}) has "
                    f"{cores:g} cores and {mb:,.0f} MB")
        return ""

    def leftovers(self) -> list[Any]:
        """Jobs of this campaign still running in the swarm (a sweep killed outright leaves them behind); the
        services of those that ended are removed (their runs are in the campaign folder)."""
        running = []
        for svc in self.client.services.list(filters={"label": f"{L_RUN}={self.label}"}):
            states = [str(t.get("Status", {}).get("State", "")) for t in svc.tasks()]
            if states and all(s in ("complete", *FAILED_STATES, "shutdown") for s in states):
                try:
                    svc.remove()
                except Exception:  # noqa: BLE001 - gone already
                    pass
            else:
                running.append(svc)
        return running

    def start(self, slot: Slot, folder: Path, record: SlotRecord, need: Need) -> SwarmJob:
        folder.mkdir(parents=True, exist_ok=True)
        before = {d.name for d in run_folders(folder)}
        attempt = new_attempt(record)
        write_record(folder, record)
        log_path = folder / f"attempt-{attempt.number}.log"
        result_path = folder / f"job-{attempt.number}.json"
        stop_path = folder / f"stop-{attempt.number}"
        result_path.unlink(missing_ok=True)
        stop_path.unlink(missing_ok=True)
        run = run_command(self.scenario.resolve(), slot, folder.resolve(), self.opts)  # the same paths on every node
        run[0] = "python3"  # the image's interpreter, not this machine's
        argv = ["python3", "-m", "mrswarm.sweep.job", "--result", str(result_path.resolve()), "--log",
                str(log_path.resolve()), "--stop", str(stop_path.resolve()), "--", *run]
        name = f"mrs-{self.label}-{attempt.number}-{hashlib.sha256(slot.name.encode()).hexdigest()[:8]}"
        svc = self.client.services.create(**service_kwargs(image=self.image, argv=argv, out=self.out, name=name,
                                                           run_label=self.label, need=need, uid=os.getuid(),
                                                           gid=os.getgid()))
        return SwarmJob(slot=slot, folder=folder, record=record, attempt=attempt, log_path=log_path,
                        result_path=result_path, stop_path=stop_path, service=svc, client=self.client, before=before)
