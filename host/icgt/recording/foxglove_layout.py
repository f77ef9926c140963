"""The Foxglove layout shipped with the package (``foxglove_layout.json``), made with the Foxglove SDK's layout types.

`python -m icgt.recording.foxglove_layout` rewrites the JSON from `build_layout()`;
tests/e2e/test_foxglove_flight.py checks that the shipped file is what this makes and that every
topic it names is in the recordings and exports. Panels: the map (vehicle track and frame
positions), the 3D view following ``base_link`` (transform tree, frame poses, camera frustum and
image), the camera image with its calibration, the device's and the recorder's logs, plots of the
clock uncertainties and of each frame's position bound and LiDAR range, and the frame records.
Import it in Foxglove: Layouts -> Import from file.
"""

from __future__ import annotations

import json
import sys

from icgt.recording import layout

CALIBRATION_OF_IMAGE = f"{layout.CAMERA_IMAGE}/calibration"  # as icgt.export.foxglove_mcap writes it


def build_layout() -> str:
    """The layout as Foxglove's layout JSON (indented, stable key order)."""
    import foxglove.layouts as fl

    def series(path: str, label: str) -> fl.PlotSeries:
        return fl.PlotSeries(value=path, label=label, timestamp_method="publishTime")

    track = fl.MapPanel(
        title="track",
        config=fl.MapConfig(
            follow_topic=layout.VEHICLE_LOCATION,
            layer="map",
            topic_colors={layout.VEHICLE_LOCATION: "#3b82f6", layout.FRAMES_LOCATION: "#f97316"},
            zoom_level=20,
        ),
    )
    # (the 3D view draws every frame of /tf and /tf_static by itself: no topic settings for them)
    scene = fl.ThreeDeePanel(
        title="3D",
        config=fl.ThreeDeeConfig(
            follow_tf=layout.BASE_FRAME,
            follow_mode="follow-position",
            topics={
                layout.FRAMES_POSE: fl.BaseRendererPoseTopicSettings(visible=True, type="axis", axis_scale=0.5),
                layout.CAMERA_CALIBRATION: fl.BaseRendererCameraTopicSettings(visible=True, distance=2.0),
                layout.CAMERA_IMAGE: fl.BaseRendererImageTopicSettings(visible=True),
            },
        ),
    )
    image = fl.ImagePanel(
        title="camera",
        config=fl.ImageConfig(
            image_mode=fl.ImageModeConfig(image_topic=layout.CAMERA_IMAGE, calibration_topic=CALIBRATION_OF_IMAGE)
        ),
    )
    device_log = fl.LogPanel(title="device log", config=fl.LogConfig(topic_to_render=layout.DEVICE_LOG_VIEW))
    host_log = fl.LogPanel(title="recorder log", config=fl.LogConfig(topic_to_render=layout.LOG))
    clocks = fl.PlotPanel(
        title="clock uncertainty [ns]",
        config=fl.PlotConfig(
            paths=[
                series(f"{layout.CLOCK_DEVICE}.uncertainty_ns", "device clock"),
                series(f"{layout.CLOCK_AUTOPILOT}.uncertainty_ns", "autopilot clock"),
            ],
            show_legend=True,
        ),
    )
    geotag = fl.PlotPanel(
        title="frames [m]",
        config=fl.PlotConfig(
            paths=[
                series(f"{layout.FRAMES}.position_error_bound_m", "position error bound"),
                series(f"{layout.FRAMES}.range_m", "LiDAR range"),
            ],
            show_legend=True,
        ),
    )
    records = fl.RawMessagesPanel(title="frame record", config=fl.RawMessagesConfig(topic_path=layout.FRAMES))

    def split(direction: str, *panels: object) -> fl.SplitContainer:
        return fl.SplitContainer(direction=direction, items=[fl.SplitItem(content=p) for p in panels])  # type: ignore[arg-type]

    content = split(
        "row",
        split("column", track, scene),
        split(
            "column",
            split("row", image, records),
            split("row", split("column", clocks, geotag), split("column", device_log, host_log)),
        ),
    )
    data = json.loads(fl.Layout(content=content).to_json())
    return json.dumps(data, indent=2, sort_keys=True) + "\n"


def main() -> int:
    layout.FOXGLOVE_LAYOUT.write_text(build_layout())
    print(f"wrote {layout.FOXGLOVE_LAYOUT}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
