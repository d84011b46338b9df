"""Poses into the neighbour table: one compiled pass for a clean edge-feed batch or direct pose, the Python rules for the rest.

Why: a UAV of 50 on the edge feed takes in about 500 poses a second. The Python path decodes
the batch, then each pose (:func:`~swarmnet.messages.accept_batched_pose`), builds a
:class:`~swarmnet.messages.Pose`, applies :meth:`NeighbourTable.update
<swarmnet.neighbours.NeighbourTable.update>` and notes the transport age: about 8 µs a pose
with the caches a UAV's tick finds, a quarter of a UAV-of-50's main thread
(docs/benchmarks.md). ``swarmnet._intake`` (``swarmnet/_intake.c``, built at install when a C
compiler is there) does all of that in one pass for a batch that every rule accepts, and
declines anything else untouched, so the Python rules still decide, name and count every
rejection: the fast path is narrower than they are, never wider (``tests/test_intake.py`` runs
both on valid, corrupted and adversarial batches and compares the tables). A direct pose (the
default network up to 25 UAVs: each neighbour's pose a message of its own) takes the same
pass, one at a time (:meth:`PoseIntake.take_pose`).

:data:`INTAKE` says which this process runs (a UAV's status file: ``net.intake``);
``MRSWARM_PURE_PYTHON=1`` in the environment chooses Python, as for the FCU's step.
"""

from __future__ import annotations

from typing import Any

from groundfloor.compiled import compiled_module
from swarmnet.messages import BATCH_VERSION, Kind, Pose, Realm, batched_pose_count, tag
from swarmnet.neighbours import Neighbour, NeighbourTable

_COMPILED = compiled_module("swarmnet._intake")
INTAKE = "compiled" if _COMPILED is not None else "python"
"""Which intake this process runs: ``"compiled"`` or ``"python"``."""


class PoseIntake:
    """The compiled fast path bound to one neighbour table (one per :class:`~swarmnet.node.SwarmNode`;
    :meth:`take` and :meth:`take_pose` only from the owner's thread, :meth:`count` from any).

    Without the compiled module :meth:`take` and :meth:`take_pose` always decline and
    :meth:`count` counts in Python, so the caller needs no second code path for that case.
    """

    __slots__ = ("table", "_fast")

    def __init__(self, table: NeighbourTable, compiled: bool = True):
        self.table = table
        self._fast: Any = None
        if compiled and _COMPILED is not None:  # the realms by wire value, the tags the feed and the UAVs write
            self._fast = _COMPILED.Intake(Pose, Neighbour, (Realm(0), Realm(1)), tag(Kind.POSE_BATCH, BATCH_VERSION),
                                          tag(Kind.POSE))

    @property
    def compiled(self) -> bool:
        return self._fast is not None

    def take(self, payload: bytes, own: int | None, at: float, srcs: list[int], ages: list[float]) -> int | None:
        """A batch that arrived at ``at`` (wall time, s) into the table, every pose but ``own``'s,
        with the rules of :meth:`NeighbourTable.update <swarmnet.neighbours.NeighbourTable.update>`;
        the id and transport age (s) of each pose the table took appended to ``srcs`` and ``ages``.
        Returns how many poses were not ``own``'s, or None, with nothing changed, when any rule
        would refuse anything in it (or there is no compiled intake): take it the Python way."""
        fast = self._fast
        if fast is None:
            return None
        return fast.take(payload, own or 0, self.table._table, at, srcs, ages)  # noqa: SLF001 - the table's own fast path

    def take_pose(self, key: str, payload: bytes, own: int | None, at: float, srcs: list[int], ages: list[float]) -> bool:
        """A direct pose that arrived at ``at`` on ``key`` (``mrs/<swarm>/<uav>/pose``) into the
        table, as :meth:`take` takes a batch's; True when it was delivered (taken by the table or
        counted there as a duplicate or late), False, with nothing changed, when any rule would
        refuse it (its key names another UAV, it is ``own``'s, it does not decode) or there is no
        compiled intake: take it the Python way."""
        fast = self._fast
        return fast is not None and fast.take_pose(key, payload, own or 0, self.table._table, at, srcs, ages) is not None  # noqa: SLF001

    def count(self, payload: bytes, exclude: int) -> int:
        """:func:`~swarmnet.messages.batched_pose_count`: the poses of UAVs other than ``exclude``
        in a batch (0 if it is not one), for the pose inlet's thread."""
        fast = self._fast
        if fast is not None:
            n: int = fast.count(payload, exclude)
            if n >= 0:
                return n
        return batched_pose_count(payload, exclude)
