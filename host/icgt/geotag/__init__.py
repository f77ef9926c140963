"""Geotagging: the frame record and the geotagger that fills it at mid-exposure."""

from icgt.geotag.config import GeotagConfig
from icgt.geotag.geotagger import Geotagger
from icgt.geotag.record import FrameFlag, FrameRecord, PositionSource

__all__ = ["FrameFlag", "FrameRecord", "GeotagConfig", "Geotagger", "PositionSource"]
