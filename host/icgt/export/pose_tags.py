"""The camera's pose in the conventions photogrammetry tools read: ODM's yaw/pitch/roll and the XMP tags.

ODM (opendm/photo.py) turns yaw, pitch, roll [deg] into a rotation with Baeumker's matrix
``Cnb = Rz(yaw) Ry(pitch) Rx(roll)`` (NED) times ``Cbb`` (swap x and y, negate z), which maps the
photogrammetric camera axes (x image right, y image up, z out of the back of the camera) to NED.
So ODM's convention, for a camera that looks straight down with the top of the image to the north,
is yaw 0, pitch 0, roll 0; pitch 90 looks forward (horizontally, towards yaw). `odm_angles`
decomposes our camera->NED quaternion exactly into these three angles, so the rotation ODM builds
from them is our camera's rotation (checked in tests/export/test_pose_tags_odm.py).

Where ODM reads them (the same rules are written down in that test):

- geo.txt columns 5-7 are used as given (ODM's convention, no per-make correction);
- XMP: in every ``rdf:Description`` of the first ``x:xmpmeta`` packet, yaw from
  ``@drone-dji:FlightYawDegree``, else ``@Camera:Yaw``/``Camera:Yaw``; pitch from
  ``@drone-dji:GimbalPitchDegree``, else ``Camera:Pitch``; roll from ``@drone-dji:GimbalRollDegree``,
  else ``Camera:Roll``; then, when the EXIF Make is DJI or Hasselblad, pitch += 90 (DJI's -90 is
  nadir), and when it is senseFly, roll is negated;
- position: EXIF GPS, but ``@drone-dji:Latitude``/``Longitude``/``AbsoluteAltitude`` replace it;
- accuracy: ``@drone-dji:RtkStdLon``/``RtkStdLat``/``RtkStdHgt`` if present, else
  ``Camera:GPSXYAccuracy``/``Camera:GPSZAccuracy`` [m] (ODM then doubles them).

OpenSfM's own EXIF reader (opensfm/exif.py, extract_opk) reads only the first rdf:Description's
attributes: ``@Camera:Yaw/Pitch/Roll`` as they are if all three are there, else the DJI gimbal
angles with pitch + 90. Pix4D and Metashape read the same DJI and Camera (Pix4D namespace) tags.
Hence what is written (all attributes of one rdf:Description):

- most cameras: ``Camera:Yaw/Pitch/Roll`` in ODM's convention (for senseFly makes Camera:Roll
  negated, ODM's rule; OpenSfM has no such rule, so it reads those files' roll with the other
  sign: no tag satisfies both);
- DJI/Hasselblad makes: ``drone-dji:GimbalYawDegree/GimbalPitchDegree/GimbalRollDegree`` in DJI's
  convention (pitch = ODM's - 90) and ``Camera:Yaw`` alone (ODM takes yaw from Flight yaw or
  Camera:Yaw, never from the gimbal's; with no Camera:Pitch/Roll OpenSfM goes to the gimbal tags);
- ``Camera:GPSXYAccuracy``/``GPSZAccuracy`` = the GPS's horizontal/vertical accuracy [m];
- removed, because ODM/OpenSfM would prefer them to ours (`CONFLICTING`): the camera's own
  drone-dji position, flight and gimbal angles and RTK accuracies, its Camera:* pose tags and a GPS
  position in its XMP (exif:GPSLatitude..., which would disagree with the new EXIF GPS). The
  values replaced are recorded in the copy (``icgt:ReplacedTags``) and in problems.csv.
"""

from __future__ import annotations

import math

import numpy as np

from icgt.geodesy import q_to_matrix

CONFLICTING: tuple[str, ...] = (
    "XMP-drone-dji:Latitude",
    "XMP-drone-dji:Longitude",
    "XMP-drone-dji:GPSLatitude",
    "XMP-drone-dji:GPSLongitude",
    "XMP-drone-dji:GPSLongtitude",
    "XMP-drone-dji:AbsoluteAltitude",
    "XMP-drone-dji:FlightYawDegree",
    "XMP-drone-dji:FlightPitchDegree",
    "XMP-drone-dji:FlightRollDegree",
    "XMP-drone-dji:GimbalYawDegree",
    "XMP-drone-dji:GimbalPitchDegree",
    "XMP-drone-dji:GimbalRollDegree",
    "XMP-drone-dji:RtkStdLon",
    "XMP-drone-dji:RtkStdLat",
    "XMP-drone-dji:RtkStdHgt",
    "XMP-drone-dji:RtkFlag",
    "XMP-Camera:Yaw",
    "XMP-Camera:Pitch",
    "XMP-Camera:Roll",
    "XMP-Camera:GPSXYAccuracy",
    "XMP-Camera:GPSZAccuracy",
    "XMP-exif:GPSLatitude",
    "XMP-exif:GPSLongitude",
    "XMP-exif:GPSAltitude",
    "XMP-exif:GPSAltitudeRef",
)
"""The camera's own tags that ODM/OpenSfM/Pix4D/Metashape would take instead of ours (ExifTool names)."""

DJI_PITCH_MAKES = ("dji", "hasselblad")
ROLL_NEGATED_MAKES = ("sensefly",)

# photogrammetric camera axes (x right, y up, z backwards) -> ours (x right, y down, z forward)
_FLIP_YZ = np.diag([1.0, -1.0, -1.0])
# ODM's Cbb: swap x and y, negate z (symmetric, its own inverse)
_CBB = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def odm_angles(q_cam_ned: tuple[float, float, float, float]) -> tuple[float, float, float]:
    """(yaw, pitch, roll) [deg] in ODM's convention of a camera->NED quaternion.

    The quaternion is (w, x, y, z), camera x right, y down, z forward, as FrameRecord.cam_q*.

    Of the two angle sets of every rotation, the one with |roll| <= 90 (a gimbal's): yaw in
    [0, 360), pitch in [-90, 270) (0 nadir, 90 level, 102 looking 12 deg up). Looking exactly
    level, ODM's pitch 90 leaves only yaw - roll defined: roll is then 0.
    """
    r_ned_cam = q_to_matrix(np.asarray(q_cam_ned, dtype=np.float64) / np.linalg.norm(q_cam_ned))
    cnb = r_ned_cam @ _FLIP_YZ @ _CBB  # Cnb = R(NED <- photogrammetric camera) Cbb^-1
    sp = max(-1.0, min(1.0, -float(cnb[2, 0])))
    pitch = math.degrees(math.asin(sp))
    if math.hypot(float(cnb[0, 0]), float(cnb[1, 0])) < 1e-9:  # pitch +-90: roll 0, yaw from the rest
        return math.degrees(math.atan2(-float(cnb[0, 1]), float(cnb[1, 1]))) % 360.0, pitch, 0.0
    yaw = math.degrees(math.atan2(float(cnb[1, 0]), float(cnb[0, 0])))
    roll = math.degrees(math.atan2(float(cnb[2, 1]), float(cnb[2, 2])))
    if abs(roll) > 90.0:  # the same rotation as (yaw + 180, 180 - pitch, roll -+ 180)
        yaw, pitch, roll = yaw + 180.0, 180.0 - pitch, roll - math.copysign(180.0, roll)
    return yaw % 360.0, pitch, roll


def odm_rotation(yaw_deg: float, pitch_deg: float, roll_deg: float) -> np.ndarray:
    """ODM's Cnb Cbb for given angles: photogrammetric camera axes -> NED (for checks and tests)."""
    y, p, r = math.radians(yaw_deg), math.radians(pitch_deg), math.radians(roll_deg)
    rz = np.array([[math.cos(y), -math.sin(y), 0.0], [math.sin(y), math.cos(y), 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[math.cos(p), 0.0, math.sin(p)], [0.0, 1.0, 0.0], [-math.sin(p), 0.0, math.cos(p)]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(r), -math.sin(r)], [0.0, math.sin(r), math.cos(r)]])
    return np.asarray(rz @ ry @ rx @ _CBB)


def is_dji_make(make: str | None) -> bool:
    return (make or "").strip().lower() in DJI_PITCH_MAKES


def xmp_pose_values(
    angles_odm: tuple[float, float, float] | None, make: str | None, h_acc_m: float | None, v_acc_m: float | None
) -> dict[str, float]:
    """The XMP pose and accuracy tags to write (ExifTool names -> values), per the module docstring."""
    out: dict[str, float] = {}
    if angles_odm is not None:
        yaw, pitch, roll = angles_odm
        low = (make or "").strip().lower()
        if low in DJI_PITCH_MAKES:
            out["XMP-drone-dji:GimbalYawDegree"] = _signed(yaw)
            out["XMP-drone-dji:GimbalPitchDegree"] = pitch - 90.0
            out["XMP-drone-dji:GimbalRollDegree"] = roll
            out["XMP-Camera:Yaw"] = yaw
        else:
            out["XMP-Camera:Yaw"] = yaw
            out["XMP-Camera:Pitch"] = pitch
            out["XMP-Camera:Roll"] = -roll if low in ROLL_NEGATED_MAKES else roll
    if h_acc_m is not None and math.isfinite(h_acc_m):
        out["XMP-Camera:GPSXYAccuracy"] = h_acc_m
    if v_acc_m is not None and math.isfinite(v_acc_m):
        out["XMP-Camera:GPSZAccuracy"] = v_acc_m
    return {k: round(v, 6) for k, v in out.items()}


def _signed(yaw_deg: float) -> float:
    """DJI writes gimbal yaw in (-180, 180]."""
    return yaw_deg - 360.0 if yaw_deg > 180.0 else yaw_deg


def img_direction(yaw_deg: float) -> float:
    """GPSImgDirection [deg] to 0.01 deg in EXIF's range 0-359.99 (359.996 is 0.00, not 360.00)."""
    value = round(yaw_deg % 360.0, 2)
    return 0.0 if value >= 360.0 else value
