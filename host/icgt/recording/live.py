"""`icgt record --live`: the recording's channels served to the Foxglove app over WebSocket as they are written.

A `RecordingSink` of `McapRecorder` (it is fed every channel and every message the file gets, as the
same bytes: same topics, schemas and encodings), served by the official Foxglove SDK's WebSocket
server (PyPI `foxglove-sdk`; Foxglove's "Foxglove WebSocket" connection, ws://127.0.0.1:PORT). Local
only by default: bind another address only on a network you trust (the protocol has no authentication).

A client that connects during the flight has missed what was sent once at the start: the last message
of each latched topic (the static mount transform, the camera calibration) is sent again when a
client subscribes to it. Messages of a topic whose channel is not declared yet are counted in
`dropped`, never raised: the file comes first.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Mapping
from typing import Any

from icgt.errors import IcgtError
from icgt.recording import layout

log = logging.getLogger(__name__)

DEFAULT_PORT = 8765
"""The Foxglove app's default port for a Foxglove WebSocket connection."""
LATCHED_TOPICS = frozenset({layout.TF_STATIC, layout.CAMERA_CALIBRATION})


class LiveViewError(IcgtError):
    """The live view's server cannot start (port in use, bad address)."""


class LiveView:
    """A Foxglove WebSocket server fed by the recorder (thread-safe: any writer thread may call it)."""

    def __init__(self, port: int = DEFAULT_PORT, host: str = "127.0.0.1") -> None:
        import foxglove

        self._foxglove = foxglove
        self._context = foxglove.Context()
        self._lock = threading.Lock()
        self._channels: dict[str, Any] = {}
        self._latched: dict[str, tuple[bytes, int]] = {}
        self.sent = 0
        self.dropped = 0
        view = self

        class _Listener(foxglove.ServerListener):  # type: ignore[misc,name-defined]
            def on_subscribe(self, client: Any, channel: Any) -> None:
                view._replay_latched(channel.topic)

        try:
            self._server = foxglove.start_server(
                name="icgt record", host=host, port=port, context=self._context, server_listener=_Listener()
            )
        except Exception as exc:  # the SDK raises its own error types (e.g. address in use)
            raise LiveViewError(f"--live {port}: cannot serve on {host}:{port}: {exc}") from None
        self.port: int = int(self._server.port)
        self.host = host
        log.info("live view: Foxglove WebSocket on ws://%s:%d", host, self.port)

    # --- RecordingSink ------------------------------------------------------------------------------
    def add_channel(
        self, topic: str, message_encoding: str, schema: tuple[str, str, bytes], metadata: Mapping[str, str]
    ) -> None:
        name, encoding, data = schema
        fg = self._foxglove
        channel = fg.Channel(
            topic,
            schema=fg.Schema(name=name, encoding=encoding, data=data),
            message_encoding=message_encoding,
            context=self._context,
            metadata=dict(metadata),
        )
        with self._lock:
            self._channels[topic] = channel

    def message(self, topic: str, data: bytes, log_time_ns: int, publish_time_ns: int) -> None:
        channel = self._channels.get(topic)
        if channel is None:
            self.dropped += 1
            return
        if topic in LATCHED_TOPICS:
            self._latched[topic] = (data, log_time_ns)
        channel.log(data, log_time=log_time_ns)
        self.sent += 1

    # --- the rest -----------------------------------------------------------------------------------
    def _replay_latched(self, topic: str) -> None:
        last = self._latched.get(topic)
        channel = self._channels.get(topic)
        if last is not None and channel is not None:
            channel.log(last[0], log_time=last[1])

    def stop(self) -> None:
        """Closes the server (clients see the connection end)."""
        try:
            self._server.stop()
        except Exception as exc:  # stopping must not hide the recording's own result
            log.warning("live view: stopping the server: %s", exc)
        log.info("live view: %d messages sent, %d before their channel was declared", self.sent, self.dropped)
