"""``mrswarm gcs foxglove``: a running swarm, live in Foxglove, over the Foxglove WebSocket protocol.

It records nothing: the same capture and translation as the flight recorder (mrswarm/recorder/),
so Foxglove shows the same topics and schemas live as in a recording (docs/recording.md), served
by Foxglove's own server (the ``foxglove-sdk`` package, the ``foxglove`` extra) on a loopback port
by default. Foxglove connects with "Open connection" -> ``ws://127.0.0.1:8765``. A channel is
advertised when its first message arrives; the server sends only what a client subscribed to.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from mrswarm.gcs.session import GcsError
from mrswarm.recorder.capture import SwarmCapture
from mrswarm.recorder.records import Record, Translator
from mrswarm.recorder.schemas import JSON, JSONSCHEMA, schema_bytes
from swarmnet.observer import SwarmObserver

POLL = 0.02  # s between two drains
DEFAULT_PORT = 8765  # Foxglove's default


def _sdk() -> Any:
    try:
        import foxglove
    except ImportError:
        raise GcsError("the live Foxglove server needs the foxglove-sdk package: pip install 'mrswarm[foxglove]'") from None
    return foxglove


class FoxgloveLive:
    """A Foxglove WebSocket server fed with a swarm's records (its own SDK context: nothing else logs into it)."""

    def __init__(self, swarm: str, host: str = "127.0.0.1", port: int = DEFAULT_PORT):
        fg = _sdk()
        self._fg = fg
        self.context = fg.Context()
        try:
            self.server = fg.start_server(name=f"mrswarm {swarm}", host=host, port=port, context=self.context)
        except Exception as exc:  # the SDK reports a busy port as a plain RuntimeError
            raise GcsError(f"cannot serve Foxglove on {host}:{port}: {exc}") from None
        self.channels: dict[str, Any] = {}

    @property
    def port(self) -> int:
        return int(self.server.port)

    def log(self, rec: Record) -> None:
        ch = self.channels.get(rec.topic)
        if ch is None:
            schema = self._fg.Schema(name=rec.schema, encoding=JSONSCHEMA, data=schema_bytes(rec.schema))
            ch = self._fg.Channel(rec.topic, schema=schema, message_encoding=JSON, context=self.context)
            self.channels[rec.topic] = ch
        ch.log(rec.data, log_time=rec.log_time)

    def close(self) -> None:
        self.server.stop()


def serve_foxglove(obs: SwarmObserver, *, host: str = "127.0.0.1", port: int = DEFAULT_PORT, duration: float | None = None,
                   stop: Callable[[], bool] = lambda: False, ready: Callable[[int], None] | None = None) -> dict[str, int]:
    """Serve ``obs``'s swarm to Foxglove until ``duration`` s pass or ``stop()``; returns what was received."""
    live = FoxgloveLive(obs.keys.swarm, host, port)
    capture = SwarmCapture(obs)
    translator = Translator(obs.keys.swarm)
    if ready is not None:
        ready(live.port)
    end = time.monotonic() + duration if duration is not None else float("inf")
    try:
        while time.monotonic() < end and not stop():
            for rec in translator.translate(capture.drain()):
                live.log(rec)
            scene = translator.scene(time.time())
            if scene is not None:
                live.log(scene)
            time.sleep(POLL)
    finally:
        capture.close()
        live.close()
    return dict(translator.received)
