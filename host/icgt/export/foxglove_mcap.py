"""`icgt export --formats mcap`: the recording enriched with the camera card's images, for Foxglove.

Writes ``foxglove.mcap`` in the export folder: every channel, message, metadata record and
attachment of the recording, as recorded, plus for every frame paired with an image of the card

* ``/camera/image`` (foxglove.CompressedImage, JPEG): a copy of the image scaled to fit
  `max_side_px` (aspect kept; never enlarged), frame ``camera_optical``;
* ``/camera/image/calibration`` (foxglove.CameraCalibration): the camera's pinhole model from the
  recording's [camera] configuration scaled to that copy's size (the recorded ``/camera/calibration``
  is for the full-size image), so Foxglove's Image panel and 3D frustum fit the picture.

A recording made before the recorder wrote the Foxglove views (no ``/vehicle/location``) gets them
here, derived from its raw telemetry, device log and frames by the recorder's own
`icgt.recording.views` (its old per-frame ``/frames/location``, ``/frames/pose`` and ``/tf`` are
replaced by theirs); each derived message is logged at its source message's log time.

The images are placed on the timeline with their frame: log time = the /frames message's log time, publish
time and timestamp = its publish time (mid-exposure on the recording's time base). The file is
written in log-time order (a reorder buffer of `REORDER_WINDOW_NS`; a message later than that is
written where it came, counted and logged), chunked, zstd-compressed and indexed by the official
`mcap` writer. Open it with ``icgt/recording/foxglove_layout.json`` for the panels.
"""

from __future__ import annotations

import heapq
import io
import logging
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import msgspec

from icgt.export import ExportError
from icgt.recording import layout

log = logging.getLogger(__name__)

FOXGLOVE_FILE = "foxglove.mcap"
CALIBRATION_TOPIC = f"{layout.CAMERA_IMAGE}/calibration"
DEFAULT_MAX_SIDE_PX = 1280
JPEG_QUALITY = 85
REORDER_WINDOW_NS = 10_000_000_000
"""Messages are held this long [ns of log time] to be written in log-time order (recordings made before
log time meant "when logged" stray from it by about a second)."""


class FoxgloveExportError(ExportError):
    """The enriched MCAP cannot be written."""


def scaled_jpeg(path: Path, max_side_px: int) -> tuple[bytes, int, int]:
    """(JPEG bytes, width, height [px]) of the image at `path` scaled to fit max_side_px (never enlarged)."""
    from PIL import Image

    try:
        with Image.open(path) as img:
            img.draft("RGB", (max_side_px, max_side_px))  # JPEG: decode at a reduced scale, much faster
            rgb = img.convert("RGB")
    except OSError as exc:
        raise FoxgloveExportError(f"{path}: cannot read the image: {exc}") from None
    rgb.thumbnail((max_side_px, max_side_px))
    out = io.BytesIO()
    rgb.save(out, "JPEG", quality=JPEG_QUALITY)
    return out.getvalue(), rgb.width, rgb.height


def _image_messages(frame_publish_ns: int, path: Path, camera: Any, max_side_px: int) -> tuple[Any, Any]:
    from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage

    from icgt.recording.views import camera_calibration

    data, w, h = scaled_jpeg(path, max_side_px)
    image = CompressedImage(frame_id=layout.CAMERA_FRAME, format="jpeg", data=data)
    image.timestamp.FromNanoseconds(frame_publish_ns)
    # fx = focal_length_mm * width_px / sensor_width_mm: the copy's own size gives its scaled intrinsics
    scaled = msgspec.structs.replace(camera, image_width_px=w, image_height_px=h)
    return image, camera_calibration(scaled, frame_publish_ns)


class _Views:
    """The recorder's Foxglove views re-derived from an old recording's raw inputs."""

    TELEMETRY = frozenset(
        layout.mavlink_topic(n) for n in ("GLOBAL_POSITION_INT", "ATTITUDE_QUATERNION", "GPS_RAW_INT")
    )

    def __init__(self, recording: Any, camera: Any, vehicle_system: int) -> None:
        from pymavlink.dialects.v20 import ardupilotmega as mavlink2

        from icgt.recording.views import TOPICS, FoxgloveViews

        self.topics = TOPICS
        offset = recording.monotonic_to_utc_offset_ns or 0
        origin = recording.enu_origin
        self.out: list[tuple[str, Any, int]] = []
        self.views = FoxgloveViews(
            camera, lambda t, m, ns: self.out.append((t, m, ns)), lambda ns: ns + offset, lambda: origin, vehicle_system
        )
        self.offset = offset
        self._mav = mavlink2.MAVLink(None)
        self.undecodable = 0
        self.started = False

    def feed(self, topic: str, data: bytes, publish_ns: int) -> list[tuple[str, Any, int]]:
        """The view messages (topic, message, publish time) one source message gives."""
        import base64
        import json

        self.out = []
        if not self.started:  # the static mount and the calibration, at the first message
            self.started = True
            self.views.start(publish_ns - self.offset)
        if topic in self.TELEMETRY:
            d = json.loads(data)
            try:
                msg = self._mav.decode(bytearray(base64.b64decode(d["raw"])))
            except Exception:  # pymavlink raises several kinds for a bad frame: counted
                self.undecodable += 1
                return []
            self.views.on_mavlink(msg, int(d["host_rx_ns"]))
        elif topic == layout.device_topic("LOG"):
            d = json.loads(data)
            self.views.on_device_log(int(d.get("level", 2)), str(d.get("text", "")), int(d.get("host_rx_ns", 0)))
        elif topic == layout.FRAMES:
            from icgt.ingest.reader import decode_frame

            self.views.on_frame(decode_frame(json.loads(data)))
        return [(t, m, ns + self.offset) for t, m, ns in self.out]


def write_foxglove_mcap(
    log_path: Path,
    out_dir: Path,
    images: Mapping[int, Path],
    camera: Any,
    *,
    max_side_px: int = DEFAULT_MAX_SIDE_PX,
    recording: Any = None,
    vehicle_system: int = 1,
) -> dict[str, int]:
    """Write OUT/foxglove.mcap; `images` maps frame_seq -> the card image paired with it.

    `camera` is the recording's GeotagConfig (`icgt.ingest.recompute.recording_config`); `recording`
    (`icgt.read`) lets the views be re-derived for a recording that lacks them. Returns counts:
    messages copied, images added, view messages derived, late messages.
    """
    from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
    from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer
    from mcap_protobuf.schema import build_file_descriptor_set

    if max_side_px < 16:
        raise FoxgloveExportError(f"image size {max_side_px} px: at least 16 px are needed")
    out = out_dir / FOXGLOVE_FILE
    counts = {"copied": 0, "images": 0, "derived": 0, "late": 0, "image_errors": 0}
    derive = None
    if recording is not None and layout.VEHICLE_LOCATION not in recording.topics():
        derive = _Views(recording, camera, vehicle_system)
    try:
        with log_path.open("rb") as src, out.open("wb") as dst:
            reader = make_reader(src)
            writer = Writer(dst, compression=CompressionType.ZSTD)
            writer.start(profile="", library="icgt export")
            schema_ids: dict[int, int] = {}
            channel_ids: dict[int, int] = {}

            def own_channel(topic: str, message_type: Any) -> int:
                fds = build_file_descriptor_set(message_type).SerializeToString()
                sid = writer.register_schema(message_type.DESCRIPTOR.full_name, "protobuf", fds)
                return writer.register_channel(topic, "protobuf", sid)

            image_channel = own_channel(layout.CAMERA_IMAGE, CompressedImage)
            calibration_channel = own_channel(CALIBRATION_TOPIC, CameraCalibration)
            view_channels = {t: own_channel(t, kind) for t, kind in derive.topics.items()} if derive else {}
            pending: list[tuple[int, int, int, bytes, int]] = []  # log, order, channel, data, publish
            order = 0
            last_written = -1

            def push(log_ns: int, channel: int, data: bytes, publish_ns: int) -> None:
                nonlocal order
                heapq.heappush(pending, (log_ns, order, channel, data, publish_ns))
                order += 1

            def flush(before_ns: int | None) -> None:
                nonlocal last_written
                while pending and (before_ns is None or pending[0][0] < before_ns):
                    log_ns, _, channel, data, publish_ns = heapq.heappop(pending)
                    if log_ns < last_written:
                        counts["late"] += 1
                    last_written = max(last_written, log_ns)
                    writer.add_message(channel, log_ns, data, publish_ns)

            newest = 0
            for schema, channel, message in reader.iter_messages(log_time_order=False):
                if derive is not None:
                    for topic, view, publish in derive.feed(channel.topic, message.data, message.publish_time):
                        push(message.log_time, view_channels[topic], view.SerializeToString(), publish)
                        counts["derived"] += 1
                    if channel.topic in view_channels:
                        continue  # the old recorder's version of a view: replaced by the derived one
                if channel.id not in channel_ids:
                    sid = 0
                    if schema is not None:
                        if schema.id not in schema_ids:
                            schema_ids[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
                        sid = schema_ids[schema.id]
                    channel_ids[channel.id] = writer.register_channel(
                        channel.topic, channel.message_encoding, sid, dict(channel.metadata)
                    )
                push(message.log_time, channel_ids[channel.id], message.data, message.publish_time)
                counts["copied"] += 1
                if channel.topic == layout.FRAMES:
                    _add_image(message, images, camera, max_side_px, push, image_channel, calibration_channel, counts)
                newest = max(newest, message.log_time)
                if pending and pending[0][0] < newest - REORDER_WINDOW_NS:
                    flush(newest - REORDER_WINDOW_NS)
            flush(None)
            for record in reader.iter_metadata():
                writer.add_metadata(record.name, dict(record.metadata))
            for attachment in reader.iter_attachments():
                writer.add_attachment(
                    attachment.create_time, attachment.log_time, attachment.name, attachment.media_type,
                    attachment.data,
                )  # fmt: skip
            writer.finish()  # type: ignore[no-untyped-call]  # mcap's Writer.finish is unannotated
    except OSError as exc:
        raise FoxgloveExportError(f"cannot write {out}: {exc.strerror or exc}") from None
    except (ValueError, KeyError) as exc:  # the mcap reader's errors for a damaged file
        raise FoxgloveExportError(f"{log_path}: cannot be read whole ({exc}): run `icgt recover` first") from None
    if counts["late"]:
        log.warning(
            "foxglove export: %d messages came more than %.0f s out of log-time order: written as they came",
            counts["late"],
            REORDER_WINDOW_NS / 1e9,
        )
    if derive is not None and derive.undecodable:
        log.warning("foxglove export: %d telemetry frames could not be decoded (no view from them)", derive.undecodable)
    if counts["image_errors"]:
        log.warning("foxglove export: %d images could not be read (not on the timeline)", counts["image_errors"])
    return counts


def _add_image(
    message: Any,
    images: Mapping[int, Path],
    camera: Any,
    max_side_px: int,
    push: Any,
    image_channel: int,
    calibration_channel: int,
    counts: dict[str, int],
) -> None:
    import json

    try:
        seq = json.loads(message.data).get("frame_seq")
    except ValueError:
        return
    path = images.get(seq) if isinstance(seq, int) else None
    if path is None:
        return
    try:
        image, calibration = _image_messages(message.publish_time, path, camera, max_side_px)
    except FoxgloveExportError as exc:
        log.warning("%s", exc)
        counts["image_errors"] += 1
        return
    push(message.log_time, image_channel, image.SerializeToString(), message.publish_time)
    push(message.log_time, calibration_channel, calibration.SerializeToString(), message.publish_time)
    counts["images"] += 1


def paired_images(pairs: Iterable[tuple[Path | None, Any, float | None]]) -> dict[int, Path]:
    """frame_seq -> image path from the export's (image, frame, residual) pairs."""
    return {frame.frame_seq: image for image, frame, _ in pairs if image is not None}
