"""Run data written so that a crash loses at most a second, and a full disk stops nothing but the records.

Each UAV writes its own trajectory (CSV, appended and flushed every second) and its
counters (JSON, replaced atomically every second) into the run's results folder; the
runner merges them afterwards.

A recording error never stops a flight process. ``ENOSPC`` (disk full), ``EDQUOT``,
``EROFS`` (read-only), ``EIO`` and every other ``OSError`` are counted in a shared
:class:`RecordHealth` and logged as a warning (the first one, then at most once a minute);
an append-only file keeps at most :data:`MAX_BACKLOG_BYTES` of unwritten rows in memory and
writes them once the disk takes them again (completing a line a partial write cut), dropping
the oldest (counted) beyond that.
"""

from __future__ import annotations

import ctypes
import errno
import fcntl
import logging
import math
import os
import signal
import sys
from pathlib import Path
from typing import Any

import msgspec

from groundfloor.files import write_atomic

log = logging.getLogger(__name__)

TRAJECTORY_COLUMNS = ("t_wall", "t_sim", "x", "y", "z", "vx", "vy", "vz", "yaw", "phase", "mode", "armed", "rtf")
# one row of TRAJECTORY_COLUMNS: s, s, m, m, m, m/s, m/s, m/s, rad, phase, mode, 0/1, RTF (-1: not measured yet)
TRAJECTORY_ROW = ",".join(["%.3f"] * 9 + ["%s", "%s", "%d", "%.3f"]) + "\n"
MAX_BACKLOG_BYTES = 256 * 1024  # per file: ~4 min of a trajectory at 10 Hz
WARN_EVERY_S = 60.0


class RecordHealth:
    """Recording errors of one process: counters for its stats file and rate-limited warnings."""

    def __init__(self) -> None:
        self.errors: dict[str, int] = {}  # errno name (ENOSPC, EROFS, EIO, ...) -> failed writes
        self.rows_dropped = 0  # rows given up for good (backlog full)
        self.bytes_dropped = 0
        self.files_not_written = 0  # whole-file replacements (counters JSON) that failed
        self.last_error = ""
        self._warned_at = -1e18

    def failed(self, path: Path, exc: OSError, now: float) -> None:
        name = errno.errorcode.get(exc.errno or 0, type(exc).__name__)
        self.errors[name] = self.errors.get(name, 0) + 1
        self.last_error = f"{path.name}: {name}: {exc.strerror or exc}"
        if now - self._warned_at >= WARN_EVERY_S:
            self._warned_at = now
            log.warning("recording degraded (%s); flight continues, counted in the stats file as 'records'", self.last_error)

    @property
    def degraded(self) -> bool:
        return bool(self.errors)

    def as_dict(self) -> dict[str, Any]:
        return {"errors": dict(self.errors), "rows_dropped": self.rows_dropped, "bytes_dropped": self.bytes_dropped,
                "files_not_written": self.files_not_written, "last_error": self.last_error}


class AppendLog:
    """An append-only text file written from a bounded in-memory backlog, whole lines in the end.

    A partial write (the disk filled up inside a line) keeps the rest of that line first in the
    backlog, so the next write completes it: nothing is lost while the backlog has room. When the
    backlog overflows, the oldest lines are dropped (counted); if that cuts the line the file ends
    in, a newline closes it first, so a reader skips just that line.
    """

    def __init__(self, path: str | Path, header: str, health: RecordHealth | None = None):
        self.path = Path(path)
        self.header = header.encode()
        self.health = health or RecordHealth()
        self._fd: int | None = None
        self._buf = bytearray()
        self._mid_line = False  # the file ends inside a line whose rest starts _buf
        self._need_newline = False  # ... whose rest was dropped: close it before writing on

    def add(self, line: str) -> None:
        """Queue one line (with its newline); :meth:`flush` writes it."""
        self._buf += line.encode()
        while len(self._buf) > MAX_BACKLOG_BYTES:
            nl = self._buf.find(b"\n")
            if nl < 0:
                break
            self.health.rows_dropped += 1
            self.health.bytes_dropped += nl + 1
            del self._buf[:nl + 1]
            if self._mid_line:
                self._mid_line, self._need_newline = False, True

    def _open(self) -> int:
        if self._fd is None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
            try:
                if os.fstat(fd).st_size == 0:
                    self._buf[0:0] = self.header
            except OSError:
                os.close(fd)
                raise
            self._fd = fd
        return self._fd

    def flush(self, now: float = 0.0) -> None:
        """Write what is queued; on an error keep it (bounded) for the next flush."""
        if not self._buf and not self._need_newline:
            return
        try:
            fd = self._open()
            if self._need_newline:
                os.write(fd, b"\n")
                self._need_newline = False
            while self._buf:
                n = os.write(fd, self._buf)
                if n <= 0:
                    break
                self._mid_line = self._buf[n - 1] != ord("\n")
                del self._buf[:n]
        except OSError as exc:
            self.health.failed(self.path, exc, now)

    def close(self, now: float = 0.0) -> None:
        self.flush(now)
        if self._fd is not None:
            try:
                os.close(self._fd)
            except OSError:
                pass
            self._fd = None


class TrajectoryRecorder:
    """``uav<N>.csv``: one row per control tick, written out so that no row waits longer than
    ``flush_every`` seconds (a process killed outright loses less than that).

    A row flushes the file when the next row, a tick later, would be past the deadline: the
    tick is the time since the row before (s, at most ``flush_every``). Flushing at the first
    tick *after* the deadline instead would let a row wait a second and a tick.
    """

    def __init__(self, path: str | Path, flush_every: float = 1.0, health: RecordHealth | None = None):
        self.path = Path(path)
        self.log = AppendLog(self.path, ",".join(TRAJECTORY_COLUMNS) + "\n", health)
        self.flush_every = flush_every
        self._last_flush = 0.0
        self._last_row = math.inf  # wall time of the row before, s (none yet: the first row's tick counts as 0)

    @property
    def health(self) -> RecordHealth:
        return self.log.health

    def write(self, now: float, row: tuple[Any, ...]) -> None:
        """Queue one row of :data:`TRAJECTORY_COLUMNS` (formatted by :data:`TRAJECTORY_ROW`, in one
        operation: a row each tick in every UAV); flush it if the next tick would be too late."""
        self.log.add(TRAJECTORY_ROW % row)
        tick = min(max(now - self._last_row, 0.0), self.flush_every)
        self._last_row = now
        if now - self._last_flush + tick >= self.flush_every:
            self.flush(now)

    def flush(self, now: float = 0.0) -> None:
        self.log.flush(now)
        self._last_flush = now

    def close(self, now: float = 0.0) -> None:
        self.log.close(now)


_encode = msgspec.json.Encoder().encode  # ~10x faster than json.dumps on the counters; NaN becomes null


LINKS_GLOB = "age_links_uav*.json"


def pool_neighbours_file_name(pool: int) -> str:
    """The file of a pool's per-neighbour pose counters (``{"pool", "written_at", "neighbours"}``),
    which its UAVs share (one neighbour table for the pool: docs/scale.md); each of their counters
    files names it in ``neighbours_in`` instead of listing every neighbour again."""
    return f"neighbours_pool{pool}.json"


def links_file_name(uav: int) -> str:
    """The file of a UAV's per-link transport-age histograms (``{"uav", "written_at",
    "transport_age_links"}``), beside its counters file ``uav<N>.json`` in the run folder."""
    return f"age_links_uav{uav}.json"


def write_json_atomic(path: str | Path, data: dict[str, Any], health: RecordHealth | None = None, now: float = 0.0) -> bool:
    """Replace ``path`` with ``data`` as JSON (temporary file, rename); False, counted, if it could not be written.

    No fsync here: it runs every second in every UAV process, and a reader already never sees
    half a file (the rename is atomic); a power cut may lose the last second, like the CSV.
    Encoded by msgspec: about 10 times faster than ``json.dumps`` on the counters.
    """
    try:
        write_atomic(path, _encode(data))
        return True
    except OSError as exc:
        if health is not None:
            health.files_not_written += 1
            health.failed(Path(path), exc, now)
        return False


def _renameat2() -> Any:
    """libc's ``renameat2`` (Linux, glibc 2.28 or later), or None."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        fn = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return None
    fn.argtypes = (ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint)
    fn.restype = ctypes.c_int
    return fn


_RENAMEAT2 = _renameat2()
_AT_FDCWD = -100
_RENAME_EXCHANGE = 2  # (linux/fs.h) the two names trade their files in one step


def _sigio_harmless() -> bool:
    """SIGIO is ignored or handled in this process (a UAV process ignores it: uav_stack.runtime).

    Why: the kernel signals a lease's holder when another process opens the file while the lease
    is held. :class:`SwappedJsonFile` holds one for microseconds and asks for SIGURG (ignored by
    default) instead, yet under a reader that opens the file thousands of times a second the
    holder was seen to get SIGIO about once per 600 000 swaps, whose default action ends the
    process. So the swap is used only where SIGIO cannot."""
    try:
        return signal.getsignal(signal.SIGIO) not in (signal.SIG_DFL, None)
    except (AttributeError, ValueError):
        return False


class SwappedJsonFile:
    """A JSON file replaced whole every second or so (a UAV's counters file), as
    :func:`write_json_atomic` replaces it, for half the CPU.

    Why: :func:`write_json_atomic` creates a file and renames it over the last one, so every
    second the file system allocates one inode and frees another: about 445 µs of CPU per write
    once a second (150 µs back to back), against 215 µs (27 µs) when the two files below are
    reused (docs/benchmarks.md).
    Here two files stay open: the new content is written into the spare (``.<name>.spare``,
    beside the file), and the two names then trade files in one step (``renameat2`` with
    ``RENAME_EXCHANGE``: Linux 3.15 and later; ext4, xfs, btrfs, tmpfs), so nothing is
    allocated or freed.

    What a reader sees is what :func:`write_json_atomic` gives: one whole version, never a mix,
    and never a change under it while it holds the file open, however long. The spare is the
    file that was named two versions ago; before writing into it, a lease (``F_SETLEASE``, which
    the kernel grants only while no other process has the file open) makes sure that no reader
    still holds it. If one does, a fresh spare is made for that write and the reader keeps its
    version. Where the swap or the lease is refused (another OS, another file system), or SIGIO
    would end the process (:func:`_sigio_harmless`), the file is written by
    :func:`write_json_atomic`. :meth:`close` removes the spare.
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.spare = self.path.with_name(f".{self.path.name}.spare")
        self._fds: tuple[int, int] | None = None  # (the spare's file, the named file's), both open
        # False: write_json_atomic each time (and where SIGIO would end the process: see _sigio_harmless)
        self.swapping = _RENAMEAT2 is not None and _sigio_harmless()
        self.fresh_spares = 0  # spares made anew because a reader still held the old one

    def write(self, data: dict[str, Any], health: RecordHealth | None = None, now: float = 0.0) -> bool:
        """Replace the file with ``data`` as JSON; False, counted, if it could not be written."""
        if self._fds is None or not self.swapping:
            ok = write_json_atomic(self.path, data, health, now)
            if ok and self.swapping and self._fds is None:
                self._open()
            return ok
        try:
            self._swap(_encode(data))
            return True
        except OSError as exc:
            self._close_fds()
            if exc.errno in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP, errno.ENOTTY):  # no swap or lease here
                self.swapping = False
            return write_json_atomic(self.path, data, health, now)  # counts it, if that fails too

    def _open_file(self, path: Path, flags: int) -> int:
        fd = os.open(path, os.O_RDWR | os.O_CLOEXEC | flags, 0o644)
        try:
            # a lease broken (someone opening the spare by its name while it is written) signals
            # the holder: SIGURG, ignored unless handled, instead of SIGIO, which would end the process
            fcntl.fcntl(fd, fcntl.F_SETSIG, signal.SIGURG)
        except OSError:
            os.close(fd)
            raise
        return fd

    def _open(self) -> None:
        """Both files open, the named one just written by :func:`write_json_atomic`."""
        try:
            spare = self._open_file(self.spare, os.O_CREAT)
        except OSError:
            self.swapping = False
            return
        try:
            named = self._open_file(self.path, 0)
        except OSError:
            os.close(spare)
            return  # (tried again at the next write)
        self._fds = (spare, named)

    def _lease(self, fd: int) -> bool:
        """A write lease on ``fd``'s file: True once no other process has it open (then released
        by :meth:`_swap`), False while one does."""
        try:
            fcntl.fcntl(fd, fcntl.F_SETLEASE, fcntl.F_WRLCK)
            return True
        except OSError as exc:
            if exc.errno in (errno.EAGAIN, errno.EBUSY):
                return False
            raise

    def _swap(self, blob: bytes) -> None:
        spare, named = self._fds  # type: ignore[misc]
        if not self._lease(spare):  # a reader still holds this version: it keeps it, a new spare takes over
            self._fds = None  # (rebuilt below; should that fail, only the named file is left to close)
            os.close(spare)
            try:
                self.spare.unlink(missing_ok=True)
                spare = self._open_file(self.spare, os.O_CREAT | os.O_EXCL)
            except OSError:
                os.close(named)
                raise
            self._fds = (spare, named)
            self.fresh_spares += 1
            if not self._lease(spare):
                raise OSError(errno.EAGAIN, "a new spare file was opened by another process")
        try:
            if os.pwrite(spare, blob, 0) != len(blob):
                raise OSError(errno.ENOSPC, "short write")
            os.ftruncate(spare, len(blob))
        finally:
            fcntl.fcntl(spare, fcntl.F_SETLEASE, fcntl.F_UNLCK)
        if _RENAMEAT2(_AT_FDCWD, os.fsencode(self.spare), _AT_FDCWD, os.fsencode(self.path), _RENAME_EXCHANGE) != 0:
            err = ctypes.get_errno()
            raise OSError(err, os.strerror(err))
        self._fds = (named, spare)  # the spare is the named file now, and the other way round

    def _close_fds(self) -> None:
        if self._fds is not None:
            for fd in self._fds:
                try:
                    os.close(fd)
                except OSError:
                    pass
            self._fds = None

    def close(self) -> None:
        """Close both files and remove the spare (the named file stays)."""
        had = self._fds is not None
        self._close_fds()
        if had:
            try:
                self.spare.unlink(missing_ok=True)
            except OSError:
                pass
