"""The synchroniser that records a flight: `icgt record`."""

from icgt.recorder.config import ConfigError, RecorderConfig, load_config
from icgt.recorder.health import RecorderStatus
from icgt.recorder.recorder import Recorder

__all__ = ["ConfigError", "Recorder", "RecorderConfig", "RecorderStatus", "load_config"]
