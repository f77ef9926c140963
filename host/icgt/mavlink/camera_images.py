"""The camera's images as MAVLink publishes them: indices, history and re-requests.

Indices (Camera Protocol v2): every image the recorder logs gets the next index, from 0, whatever caused
it (a ground-station command, the control socket, an interval, a manual shot on the camera seen by the
hot-shoe line): image N's CAMERA_IMAGE_CAPTURED.image_index is N and CAMERA_CAPTURE_STATUS.image_count is
the number of images so far, so the newest image is image_count - 1. The device numbers its triggers
itself (FrameRecord.image_index, 0 for an unsolicited exposure); the log's ``/camera/images`` topic maps
each MAVLink index to its frame (``frame_seq``) and the device's trigger number.

The poor-pose policy (which frames are published without a position) is the recorder's
(`icgt.recorder.camera_link`): this module carries what it decides.

History: every image of the recording is kept, packed, in a temporary file (`icgt.spill`; a few kB of
memory whatever the length) and can be re-requested with MAV_CMD_REQUEST_MESSAGE(CAMERA_IMAGE_CAPTURED):
param2 the first index (-1: all images), param3 0 for that image only, -1 for it and every later one, or
the last index of a range.
"""

from __future__ import annotations

import dataclasses
import math
import struct
import threading
from typing import Any

from icgt.errors import IcgtError
from icgt.mavlink.sample_codec import SampleCodec
from icgt.spill import Spill

__all__ = [
    "CameraError",
    "CapturedImage",
    "ImageHistory",
    "encode_image_captured",
    "image_range",
    "truncate_utf8",
]


class CameraError(IcgtError):
    """A camera message cannot be built from the values given (e.g. a latitude out of range)."""


@dataclasses.dataclass(frozen=True, slots=True)
class CapturedImage:
    """One exposure for CAMERA_IMAGE_CAPTURED, in SI units (the component converts to MAVLink's).

    ``image_index``: assigned by `CameraComponent.publish_image_captured` (-1 until then). ``time_boot_ms``:
    the component's boot clock (`CameraComponent.time_boot_ms`). ``time_utc_us``: 0 when unknown.
    ``relative_alt_m``: height above home. A position or attitude that is None is sent as 0 (lat, lon,
    alt, relative_alt) and NaN (q)."""

    time_boot_ms: int
    time_utc_us: int
    lat_deg: float | None
    lon_deg: float | None
    alt_msl_m: float | None
    relative_alt_m: float | None
    q_wxyz: tuple[float, float, float, float] | None
    capture_result: bool = True
    file_url: str = ""
    camera_id: int = 0
    image_index: int = -1


def _scaled(value: float | None, scale: float, limit: int, what: str) -> int:
    if value is None:
        return 0
    if not math.isfinite(value):
        raise CameraError(f"{what} is not finite: {value}")
    out = round(value * scale)
    if abs(out) > limit:
        raise CameraError(f"{what} out of range: {value}")
    return out


def truncate_utf8(text: str, size: int) -> bytes:
    """`text` as UTF-8 in at most `size` bytes, cut at a character boundary (MAVLink char[] fields)."""
    return text.encode("utf-8")[:size].decode("utf-8", errors="ignore").encode("utf-8")


def check_image(image: CapturedImage) -> None:
    """Raise CameraError for a value CAMERA_IMAGE_CAPTURED cannot carry."""
    _scaled(image.lat_deg, 1e7, 900_000_000, "latitude")
    _scaled(image.lon_deg, 1e7, 1_800_000_000, "longitude")
    _scaled(image.alt_msl_m, 1e3, 2**31 - 1, "altitude")
    _scaled(image.relative_alt_m, 1e3, 2**31 - 1, "relative altitude")
    if image.q_wxyz is not None and len(image.q_wxyz) != 4:
        raise CameraError("q_wxyz needs 4 components")
    if not 0 <= image.image_index < 2**31 and image.image_index != -1:
        raise CameraError(f"image index out of range: {image.image_index}")


def encode_image_captured(mav: Any, image: CapturedImage) -> Any:
    """The CAMERA_IMAGE_CAPTURED message of ``image`` (pymavlink ``mav`` packs it)."""
    check_image(image)
    q = [math.nan] * 4 if image.q_wxyz is None else [float(c) for c in image.q_wxyz]
    return mav.camera_image_captured_encode(
        image.time_boot_ms & 0xFFFFFFFF,
        max(0, image.time_utc_us),
        image.camera_id & 0xFF,
        _scaled(image.lat_deg, 1e7, 900_000_000, "latitude"),
        _scaled(image.lon_deg, 1e7, 1_800_000_000, "longitude"),
        _scaled(image.alt_msl_m, 1e3, 2**31 - 1, "altitude"),
        _scaled(image.relative_alt_m, 1e3, 2**31 - 1, "relative altitude"),
        q,
        image.image_index,
        1 if image.capture_result else 0,
        truncate_utf8(image.file_url, 205),
    )


def image_range(first: float, last: float, count: int) -> tuple[range, str]:
    """The indices a CAMERA_IMAGE_CAPTURED request asks for (REQUEST_MESSAGE param2, param3) among
    ``count`` images, and why it is empty when it is."""
    if not math.isfinite(first) or first != int(first) or first < -1:
        return range(0), f"param2 {first}: an image index or -1 (all) is needed"
    if not math.isfinite(last) or last != int(last) or last < -1:
        return range(0), f"param3 {last}: 0 (one image), -1 (all later ones) or the last index is needed"
    if count == 0:
        return range(0), "no images yet"
    a = int(first)
    if a == -1:
        return range(count), ""
    b = int(last)
    if b == 0:
        b = a
    elif b == -1:
        b = count - 1
    if b < a:
        return range(0), f"range {a}..{b} is empty"
    if a >= count:
        return range(0), f"image {a} not taken yet ({count} images, indices 0..{count - 1})"
    return range(a, min(b, count - 1) + 1), ""


class ImageHistory:
    """Every image published in this recording, by index. Thread-safe."""

    def __init__(self) -> None:
        # Packed (`SampleCodec`: one fixed-size struct per image) and kept on disk in a `Spill`, image N at
        # N * size: the history grows with the recording (a ground station may re-request any image, 300 a
        # minute at 5 fps), and in memory, even packed, it made the resident set grow (issue 30's soak). An
        # image whose file_url would overflow the codec's string table is kept in memory as the object.
        self._codec = SampleCodec(CapturedImage)
        self._spill = Spill("the camera's image history")  # in the temporary directory
        self._unpacked: dict[int, CapturedImage] = {}
        self._count = 0
        self._lock = threading.Lock()

    def append(self, image: CapturedImage) -> CapturedImage:
        """Give ``image`` the next index, keep it and return it with its index."""
        with self._lock:
            indexed = dataclasses.replace(image, image_index=self._count)
            try:
                packed = self._codec.encode(indexed)
            except (ValueError, struct.error):  # a string table full, or an int beyond its field
                packed = bytes(self._codec.size)  # a placeholder slot keeps image N at N * size
                self._unpacked[indexed.image_index] = indexed
            self._spill.append(packed)
            self._count += 1
            return indexed

    def __len__(self) -> int:
        with self._lock:
            return self._count

    def get(self, index: int) -> CapturedImage | None:
        with self._lock:
            if not 0 <= index < self._count:
                return None
            unpacked = self._unpacked.get(index)
            if unpacked is not None:
                return unpacked
            size = self._codec.size
            return self._codec.decode(self._spill.read(index * size, size))
