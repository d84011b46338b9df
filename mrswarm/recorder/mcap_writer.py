"""An MCAP file that survives its writer being killed: chunks closed and flushed every second.

The file is written with the ``mcap`` package (pure Python): records go into a zstd-compressed
chunk, and :meth:`McapWriter.maybe_flush` closes the chunk, writes it with its message index and
fsyncs at least every :data:`FLUSH_EVERY` s. A writer killed with SIGKILL therefore leaves a file
whose complete chunks hold everything but the last second; it has no summary section (indexes,
statistics), which a reader rebuilds by reading the chunks in order (mrswarm/recorder/reader.py,
and Foxglove does the same). :meth:`McapWriter.close` writes the summary.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path

from mcap.writer import CompressionType, Writer

from mrswarm.recorder.records import Record
from mrswarm.recorder.schemas import JSON, JSONSCHEMA, schema_bytes
from swarmnet.version import __version__

FLUSH_EVERY = 1.0  # s: at most this much is lost when the writer dies
CHUNK_BYTES = 4 * 1024 * 1024  # a chunk closes earlier when it reaches this size (uncompressed)


class McapWriter:
    """Writes :class:`~mrswarm.recorder.records.Record` s to ``path`` (which must not exist yet)."""

    def __init__(self, path: str | Path, *, flush_every: float = FLUSH_EVERY, clock: Callable[[], float] = time.monotonic):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._f = open(self.path, "xb")  # noqa: SIM115 (open until close()); "x": never overwrite a recording
        self._w = Writer(self._f, chunk_size=CHUNK_BYTES, compression=CompressionType.ZSTD)
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

    def maybe_flush(self) -> None:
        if self.clock() - self._last_flush >= self.flush_every:
            self.flush()

    def flush(self) -> None:
        """Close the chunk in progress, write it out and fsync: what is flushed survives a SIGKILL."""
        self._w.flush()
        try:
            os.fsync(self._f.fileno())
        except OSError:
            pass
        self._last_flush = self.clock()

    def close(self) -> None:
        """Write the summary (indexes, statistics) and close the file."""
        if self._closed:
            return
        self._closed = True
        try:
            self._w.finish()
            self._f.flush()
            os.fsync(self._f.fileno())
        finally:
            self._f.close()
