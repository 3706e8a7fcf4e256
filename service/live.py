"""``pvtflow serve --live [PORT]``: the recording's channels served live (the Foxglove WebSocket protocol).

The Foxglove SDK's server (``foxglove-sdk``) on 127.0.0.1 only, with a context of its own (no other
logging of the process reaches it). The ``Recorder`` (service/recording) hands every message it
writes to the server too, already encoded, so a viewer sees exactly what a recording holds, with
the same schemas and the bus's clock; with ``--live`` and no ``--record`` the recorder writes no
file. A message for a channel no client subscribes to costs a dictionary lookup.
"""

from __future__ import annotations

import json
import threading
from typing import Any

DEFAULT_PORT = 8765
HOST = "127.0.0.1"
# messages queued per client before the oldest are dropped: a run's start writes a quarter second of
# plan for every axis at once (service/recording/planned.py, PLANNED_LEAD_MS), a few thousand messages
BACKLOG = 16384


class LiveError(Exception):
    """The live server cannot start (one line for the user)."""


class LiveServer:
    """``LiveServer(port).start()``; ``log(topic, schema, log_time_ns, data)``; ``stop()``."""

    def __init__(self, port: int = DEFAULT_PORT, name: str = "pvtflow") -> None:
        self.port = port
        self.name = name
        self._server: Any = None
        self._context: Any = None
        self._channels: dict[str, Any] = {}  # topic -> the native log call of its channel
        self._lock = threading.Lock()

    def start(self) -> LiveServer:
        import foxglove

        self._context = foxglove.Context()
        try:
            self._server = foxglove.start_server(
                name=self.name, host=HOST, port=self.port, context=self._context, message_backlog_size=BACKLOG
            )
        except Exception as exc:  # the SDK raises its own error type for a port in use
            raise LiveError(f"--live {self.port}: cannot serve on {HOST}:{self.port}: {exc}") from None
        self.port = int(self._server.port)
        return self

    @property
    def url(self) -> str:
        return f"ws://{HOST}:{self.port}"

    def log(self, topic: str, schema: dict[str, Any], log_time_ns: int, data: bytes) -> None:
        log_bytes = self._channels.get(topic)
        if log_bytes is None:
            with self._lock:
                log_bytes = self._channels.get(topic)
                if log_bytes is None:
                    log_bytes = self._channels[topic] = new_channel(self._context, topic, schema).base.log
        log_bytes(data, log_time_ns, None)

    def stop(self) -> None:
        if self._server is not None:
            self._server.stop()
            self._server = None


def new_channel(context: Any, topic: str, schema: dict[str, Any]) -> Any:
    """A Foxglove SDK channel of ``context`` for ``topic``: JSON messages, ``schema`` as JSON schema.
    Messages already encoded go to its ``base.log(data, log_time, None)``, the native call the
    channel's own ``log`` ends in after its type checks."""
    import foxglove

    return foxglove.Channel(
        topic,
        schema=foxglove.Schema(name=str(schema["title"]), encoding="jsonschema", data=json.dumps(schema).encode()),
        message_encoding="json",
        context=context,
    )
