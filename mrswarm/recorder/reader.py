"""Reading a recording back, including one whose writer was killed (no summary, a torn last chunk).

:func:`read_recording` streams the file from the start with the ``mcap`` package's stream reader
(which unpacks each chunk), so it needs no index: a complete file and a cut one read the same way,
the cut one up to its last complete chunk. Messages come in file order, which is arrival order.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

from mcap.exceptions import McapError
from mcap.records import Attachment, Channel, DataEnd, Footer, Message, Metadata, Schema
from mcap.stream_reader import StreamReader

from groundfloor.errors import MrswarmError


class RecordingError(MrswarmError):
    """Not an MCAP file, or not one this recorder wrote."""


class RecordedMessage(NamedTuple):
    topic: str
    schema: str
    log_time: int  # ns, arrival at the recorder
    publish_time: int  # ns, the sender's stamp
    sequence: int
    data: bytes  # JSON

    def json(self) -> Any:
        return json.loads(self.data)


@dataclass
class Recording:
    """What :func:`read_recording` found besides the messages (filled in as the stream is read)."""

    path: Path
    attachments: dict[str, bytes] = field(default_factory=dict)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    complete: bool = False  # the file ends with its summary (the writer closed it)
    error: str | None = None  # why reading stopped early (a torn chunk after a crash)
    messages: int = 0


def read_recording(path: str | Path, recording: Recording | None = None,
                   topics: Iterable[str] | None = None) -> Iterator[RecordedMessage]:
    """Every message of ``path`` in file order (optionally only ``topics``); fills ``recording`` as it goes."""
    rec = recording if recording is not None else Recording(Path(path))
    wanted = set(topics) if topics is not None else None
    schemas: dict[int, str] = {}
    channels: dict[int, tuple[str, str]] = {}
    try:
        f = open(path, "rb")  # noqa: SIM115 (closed by the with below)
    except OSError as exc:
        raise RecordingError(f"{path}: {exc.strerror or exc}") from None
    with f:
        if f.read(8) != b"\x89MCAP0\r\n":
            raise RecordingError(f"{path}: not an MCAP file")
        f.seek(0)
        try:
            for r in StreamReader(f, record_size_limit=1 << 30).records:
                if isinstance(r, Message):
                    ch = channels.get(r.channel_id)
                    if ch is None or (wanted is not None and ch[0] not in wanted):
                        continue
                    rec.messages += 1
                    yield RecordedMessage(ch[0], ch[1], r.log_time, r.publish_time, r.sequence, r.data)
                elif isinstance(r, Channel):
                    channels[r.id] = (r.topic, schemas.get(r.schema_id, ""))
                elif isinstance(r, Schema):
                    schemas[r.id] = r.name
                elif isinstance(r, Attachment):
                    rec.attachments[r.name] = r.data
                elif isinstance(r, Metadata):
                    rec.metadata[r.name] = dict(r.metadata)
                elif isinstance(r, DataEnd | Footer):
                    rec.complete = True
                    if isinstance(r, Footer):
                        break
        except (McapError, EOFError, struct.error, ValueError) as exc:
            rec.error = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
