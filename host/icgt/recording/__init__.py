"""Recording to MCAP: the crash-safe recorder, the JSON Schemas of the self-describing topics, recovery.

Every time in this package is nanoseconds since the Unix epoch (UTC) unless its name says otherwise.
"""

from icgt.field_doc import Doc
from icgt.recording.recover import RecoveryReport, recover
from icgt.recording.schemas import SchemaError, encode_json, json_encoder, json_schema, schema_name
from icgt.recording.writer import (
    McapFileWriter,
    McapLogHandler,
    McapRecorder,
    RecordingError,
    RecordingStats,
)

__all__ = [
    "Doc",
    "McapFileWriter",
    "McapLogHandler",
    "McapRecorder",
    "RecordingError",
    "RecordingStats",
    "RecoveryReport",
    "SchemaError",
    "encode_json",
    "json_encoder",
    "json_schema",
    "recover",
    "schema_name",
]
