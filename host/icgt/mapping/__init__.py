"""The global damage map: detections from any detector placed on the structure, merged, measured, mosaicked.

`icgt map LOG --images CARD --detections DET --out DIR` (icgt.mapping.cli) reads the recording with
`icgt.read`, pairs the card's images with its frames (icgt.ingest.match), reads the detector's
output (detections.py), places every detection on the structure's surface with
`icgt.geometry.Projector` (place.py), merges the detections of one defect seen in several
overlapping images into one instance (merge.py), checks each by multi-view consensus (consensus.py:
confirmed or doubtful, with how many images saw it and could have), and writes GeoJSON (geojson.py)
and a direct-projection mosaic of the face (mosaic.py). pixel_detector.py is a classical crack
detector on the card's JPEGs that writes COCO for it. `icgt tiles` (tiles.py) cuts the images into the
paper's 512 x 512 detector tiles with each tile's place on the face, so tile detections map back.

Conventions and units:

- Image pixels: OpenCV's (integer coordinates are pixel centres, icgt.geometry). COCO polygon
  coordinates count from the pixel's corner (COCO's convention) and are shifted by -0.5 px when
  read; YOLO's normalised coordinates are x * width - 0.5. Detections are in the pixels of the
  image file the detector was given; a card image smaller than the calibration (a downscaled copy)
  is scaled to the calibration's resolution (same aspect ratio required).
- Face coordinates (s, t) [m]: on the surface plane, from the face origin (the --plane point, or
  the centroid of the LiDAR returns the plane was fitted to) along `icgt.geometry.plane_axes` of its
  normal (a vertical face seen from the drone: s right, t up). The face frame is written with
  every output (map.json) in the recording's ENU frame and in WGS84.
- World: WGS84 longitude/latitude [deg] in GeoJSON (RFC 7946, [lon, lat]); heights above mean sea
  level [m] as a property (alt_msl_m), like the recording's.
- Lengths and widths in mm, areas in mm^2, uncertainties as 1-sigma in mm.
"""

from icgt.errors import IcgtError


class MappingError(IcgtError):
    """A damage-map input that cannot be used (detections file, images, surface); the message says which."""


__all__ = ["MappingError"]
