"""An MCAP file that survives its writer being killed, and a full disk: whole records on disk, flushed every second.

The file is written with the ``mcap`` package (pure Python): records go into a zstd-compressed
chunk, and :meth:`McapWriter.maybe_flush` closes the chunk, writes it with its message index and
fsyncs at least every :data:`FLUSH_EVERY` s. The ``mcap`` writer writes into memory
(:class:`_Sink`), and only whole records reach the file, at those flushes: a writer killed with
SIGKILL leaves a file whose records are complete up to its last flush (everything but the last
second), and a write the disk refuses (full, read-only, failing) is cut back to the last whole
record (:class:`DiskError`), so the file stays readable up to the fault. Such a file has no summary
section (indexes, statistics), which a reader rebuilds by reading the records in order
(mrswarm/recorder/reader.py, and Foxglove does the same); :func:`seal` gives it the ending a closed
file has (DataEnd, Footer), and :meth:`McapWriter.close` writes the whole summary.
"""

from __future__ import annotations

import os
import struct
import time
from collections.abc import Callable
from pathlib import Path

from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import DataEnd, Footer
from mcap.writer import CompressionType, Writer

from groundfloor.errors import MrswarmError
from mrswarm.recorder.records import Record
from mrswarm.recorder.schemas import JSON, JSONSCHEMA, schema_bytes
from swarmnet.version import __version__

FLUSH_EVERY = 1.0  # s: at most this much is lost when the writer dies
CHUNK_BYTES = 4 * 1024 * 1024  # a chunk closes earlier when it reaches this size (uncompressed)
MAGIC = b"\x89MCAP0\r\n"
_RECORD_HEAD = struct.Struct("<BQ")  # opcode, content length


class DiskError(OSError, MrswarmError):
    """The disk refused the file's next records; the file is cut back to its last whole record."""


class _Sink:
    """The stream the ``mcap`` writer writes to: bytes held in memory until :meth:`commit` writes them."""

    def __init__(self, fd: int):
        self.fd = fd
        self.committed = 0  # bytes on disk, all of them whole records
        self.pending = bytearray()

    def write(self, data: bytes) -> int:
        self.pending += data
        return len(data)

    def tell(self) -> int:
        return self.committed + len(self.pending)

    def flush(self) -> None:
        return None

    def close(self) -> None:
        return None

    def commit(self) -> None:
        """Write what is pending; on a refusal, cut the file back to its last whole record and raise DiskError
        (what was pending stays pending: the next commit tries it again, at the same offset)."""
        view = memoryview(self.pending)
        done = 0
        try:
            while done < len(view):
                done += os.pwrite(self.fd, view[done:], self.committed + done)
        except OSError as exc:
            view.release()
            try:
                os.ftruncate(self.fd, self.committed)
            except OSError:
                pass
            raise DiskError(exc.errno, exc.strerror, exc.filename) from None
        view.release()
        self.committed += done
        self.pending.clear()


class McapWriter:
    """Writes :class:`~mrswarm.recorder.records.Record` s to ``path`` (which must not exist yet)."""

    def __init__(self, path: str | Path, *, flush_every: float = FLUSH_EVERY, clock: Callable[[], float] = time.monotonic):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o644)  # never overwrite a recording
        self._sink = _Sink(self._fd)
        self._w = Writer(self._sink, chunk_size=CHUNK_BYTES, compression=CompressionType.ZSTD)  # type: ignore[arg-type]
        self._w.start(profile="", library=f"mrswarm {__version__}")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self.flush_every = flush_every
        self.clock = clock
        self._last_flush = clock()
        self.messages = 0
        self._closed = False

    def _channel(self, topic: str, schema: str) -> int:
        cid = self._channels.get(topic)
        if cid is None:
            sid = self._schemas.get(schema)
            if sid is None:
                sid = self._schemas[schema] = self._w.register_schema(schema, JSONSCHEMA, schema_bytes(schema))
            cid = self._channels[topic] = self._w.register_channel(topic, JSON, sid)
        return cid

    def write(self, rec: Record) -> None:
        self._w.add_message(self._channel(rec.topic, rec.schema), rec.log_time, rec.data, rec.publish_time, rec.sequence)
        self.messages += 1

    def attach(self, name: str, data: bytes, media_type: str, t: float | None = None) -> None:
        """A file kept inside the recording (the scenario, the run's counters): flushed at once."""
        now = int((time.time() if t is None else t) * 1e9)
        self._w.flush()
        self._w.add_attachment(now, now, name, media_type, data)
        self.flush()

    def metadata(self, name: str, data: dict[str, str]) -> None:
        self._w.flush()
        self._w.add_metadata(name, data)
        self.flush()

    def maybe_flush(self) -> bool:
        """Flush if the last flush is :attr:`flush_every` old; whether it did (DiskError as :meth:`flush`)."""
        if self.clock() - self._last_flush >= self.flush_every:
            self.flush()
            return True
        return False

    @property
    def unflushed(self) -> int:
        """Messages not on disk yet (since the last flush the disk took)."""
        return self.messages - self._flushed_messages

    @property
    def backlog(self) -> int:
        """Bytes waiting in memory for the disk (after a refusal; 0 otherwise between flushes)."""
        return len(self._sink.pending)

    _flushed_messages = 0

    def flush(self) -> None:
        """Close the chunk in progress, write it out and fsync: what is flushed survives a SIGKILL. DiskError
        if the disk refuses it: the file then ends at the last flush, and the records stay in memory
        (:attr:`backlog`) for the next flush to try again."""
        self._w.flush()
        self._last_flush = self.clock()
        self._sink.commit()
        self._flushed_messages = self.messages
        try:
            os.fsync(self._fd)
        except OSError:
            pass

    def close(self) -> None:
        """Write the summary (indexes, statistics) and close the file. DiskError if the disk refuses it: the
        file is then sealed at its last flush instead (readable, without the summary)."""
        if self._closed:
            return
        self._closed = True
        try:
            self._w.finish()
            self._sink.commit()
            os.fsync(self._fd)
        except DiskError:
            seal_fd(self._fd, self._sink.committed)
            raise
        finally:
            os.close(self._fd)

    def abandon(self) -> None:
        """After a DiskError: stop writing; the file ends with its last flush, sealed (DataEnd, Footer) if there is room."""
        if self._closed:
            return
        self._closed = True
        try:
            seal_fd(self._fd, self._sink.committed)
        finally:
            os.close(self._fd)


def _ending() -> bytes:
    b = RecordBuilder()
    DataEnd(data_section_crc=0).write(b)
    Footer(summary_start=0, summary_offset_start=0, summary_crc=0).write(b)
    return bytes(b.end()) + MAGIC


def whole_records_end(fd: int) -> tuple[int, bool]:
    """(offset after the file's last whole record, whether that record is the Footer): the MCAP framing
    (opcode, length, content) walked from the start, without reading the contents."""
    size = os.fstat(fd).st_size
    if size < len(MAGIC) or os.pread(fd, len(MAGIC), 0) != MAGIC:
        return 0, False
    pos = len(MAGIC)
    while pos + _RECORD_HEAD.size <= size:
        op, length = _RECORD_HEAD.unpack(os.pread(fd, _RECORD_HEAD.size, pos))
        end = pos + _RECORD_HEAD.size + length
        if end > size:
            break
        pos = end
        if op == Opcode.FOOTER:
            return pos, True
    return pos, False


def seal_fd(fd: int, end: int | None = None) -> bool:
    """Give a file its ending (DataEnd, Footer, magic) after its last whole record (or at ``end``), cutting off a
    torn tail; a file that has its Footer already is left as it is. False if the disk refused it."""
    last, footed = whole_records_end(fd)
    if footed:
        return True
    end = last if end is None else min(end, last)
    if end < len(MAGIC):
        return False
    try:
        os.ftruncate(fd, end)
        ending = _ending()
        if os.pwrite(fd, ending, end) != len(ending):
            os.ftruncate(fd, end)
            return False
        os.fsync(fd)
    except OSError:
        try:
            os.ftruncate(fd, end)
        except OSError:
            pass
        return False
    return True


def seal(path: str | Path) -> bool:
    """:func:`seal_fd` on a file whose writer died (killed, or its disk full): it then ends as a closed file does."""
    try:
        fd = os.open(path, os.O_RDWR)
    except OSError:
        return False
    try:
        return seal_fd(fd)
    finally:
        os.close(fd)
