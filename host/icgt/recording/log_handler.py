"""Python log records on a foxglove.Log topic of a recorder (Foxglove's Log panel shows them)."""

from __future__ import annotations

import logging
from typing import Any, Protocol

from foxglove_schemas_protobuf.Log_pb2 import Log

from icgt.recording.mcap_file import RecordingError

__all__ = ["McapLogHandler"]


_LOG_LEVELS = (
    (logging.CRITICAL, Log.FATAL),
    (logging.ERROR, Log.ERROR),
    (logging.WARNING, Log.WARNING),
    (logging.INFO, Log.INFO),
)


class LogSink(Protocol):
    """What the handler writes to (an `icgt.recording.writer.McapRecorder`)."""

    def write(
        self, topic: str, message: Any, log_time_ns: int | None = None, publish_time_ns: int | None = None
    ) -> None: ...


class McapLogHandler(logging.Handler):
    """Records Python log records on a foxglove.Log topic of a recorder (Foxglove's Log panel shows them)."""

    def __init__(self, recorder: LogSink, topic: str = "/icgt/log", level: int = logging.INFO) -> None:
        super().__init__(level)
        self._recorder = recorder
        self._topic = topic

    def emit(self, record: logging.LogRecord) -> None:
        try:
            time_ns = int(record.created * 1e9)  # LogRecord.created: float seconds since the Unix epoch
            level = next((fox for py, fox in _LOG_LEVELS if record.levelno >= py), Log.DEBUG)
            message = Log(
                level=level, message=self.format(record), name=record.name, file=record.pathname, line=record.lineno
            )
            message.timestamp.FromNanoseconds(time_ns)
            self._recorder.write(self._topic, message, publish_time_ns=time_ns)  # logged now, in file order
        except RecordingError:
            pass  # the recorder has stopped and reports that itself; logging it here would loop
        except Exception:  # logging must never take the program down
            self.handleError(record)
