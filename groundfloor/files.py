"""A file replaced atomically: written beside its name, then renamed over it.

A reader (another process, the runner, a user's script) sees the old content or the new one,
never half a file, and a write the disk refuses (full, read-only) leaves the old file whole and
no temporary file behind; the ``OSError`` goes to the caller, who counts it or reports it.

``fsync=True`` also makes the new content durable (the file and its folder synced, so it
survives a power cut); it costs a disk flush, so files rewritten every second (a UAV's counters)
go without it and a power cut may lose their last second. ``private=True`` creates the file
readable by its owner only (0600 from the first byte: keys and tokens).
"""

from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any


def temporary_name(path: Path) -> Path:
    """Where ``path``'s next version is written before the rename: beside it, hidden, one per process."""
    return path.with_name(f".{path.name}.{os.getpid()}.tmp")


@contextlib.contextmanager
def replacing(path: str | Path, *, fsync: bool = False, private: bool = False) -> Iterator[IO[bytes]]:
    """A binary file to write ``path``'s new content into; it replaces ``path`` when the block ends
    without an exception (and is removed if one is raised)."""
    path = Path(path)
    tmp = temporary_name(path)
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600 if private else 0o666)
        if private:
            os.fchmod(fd, 0o600)  # O_CREAT's mode is filtered by the umask; this is not
        with os.fdopen(fd, "wb") as f:
            yield f
            f.flush()
            if fsync:
                os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        try:
            tmp.unlink(missing_ok=True)
        except OSError:  # a read-only disk refuses it too (and took no temporary file)
            pass
    if fsync:
        dir_fd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(dir_fd)
        finally:
            os.close(dir_fd)


def write_atomic(path: str | Path, data: bytes | str, *, fsync: bool = False, private: bool = False) -> None:
    """Replace ``path`` with ``data`` (text is written as UTF-8). Raises ``OSError``."""
    with replacing(path, fsync=fsync, private=private) as f:
        f.write(data.encode() if isinstance(data, str) else data)


def write_json_atomic(path: str | Path, obj: Any, *, indent: int | None = None, fsync: bool = False) -> None:
    """Replace ``path`` with ``obj`` as JSON (``json.dumps`` with ``indent``). Raises ``OSError``."""
    write_atomic(path, json.dumps(obj, indent=indent), fsync=fsync)
