"""Geotagging: the frame record and the geotagger that fills it at mid-exposure."""

from icgt.geotag.geotagger import GeotagConfig, Geotagger
from icgt.geotag.record import FrameFlag, FrameRecord, PositionSource

__all__ = ["FrameFlag", "FrameRecord", "GeotagConfig", "Geotagger", "PositionSource"]
