"""The simulated camera card, read back with exifread (not the library that wrote it)."""

from __future__ import annotations

import dataclasses
from datetime import UTC, datetime
from pathlib import Path

import exifread
import msgspec
import pytest
from PIL import Image

from icgt.sim.camera_card import file_name, read_frame_number, write_card
from icgt.sim.scenario import Camera, Scenario, load_scenario
from icgt.sim.truth import ClockMaps, exposure_truth

UTC0_US = 1_718_000_000_000_000  # 2024-06-10 06:13:20 UTC


def exposures(sc: Scenario, clocks: ClockMaps) -> list:
    """Frames 1, 2, 3 triggered, trigger 3 missed by the camera, frame 4 a manual shot."""

    def event(frame: int, trigger: int, tau: float, manual: bool = False) -> dict[str, object]:
        start = round(float(clocks.tau_to_device_us(tau)))
        return {
            "event": "exposure",
            "frame_number": frame,
            "trigger_index": trigger,
            "trigger_t_us": start,
            "start_t_us": start,
            "end_t_us": start + 1000,
            "manual": manual,
        }

    events = [event(1, 1, 2.004), event(2, 2, 2.204), event(3, 4, 2.604), event(4, 0, 3.333, manual=True)]
    return exposure_truth(sc, events, clocks)


def tags_of(path: Path) -> dict[str, str]:
    with path.open("rb") as f:
        return {k: str(v) for k, v in exifread.process_file(f, details=False).items()}


def camera_time(clocks: ClockMaps, tau: float) -> datetime:
    return datetime.fromtimestamp(clocks.tau_to_camera_s(tau), tz=UTC)


@pytest.mark.parametrize("resolution", ["1s", "10ms"])
def test_card_names_and_exif_times(tmp_path: Path, resolution: str) -> None:
    sc = load_scenario("hover")
    clocks = dataclasses.replace(ClockMaps.from_scenario(sc, 0, UTC0_US), exif_resolution=resolution)
    truth = exposures(sc, clocks)
    camera = msgspec.structs.replace(sc.camera, first_file_number=98)
    paths = write_card(tmp_path / "DCIM", truth, clocks, camera)
    assert [p.name for p in paths] == ["DSC00098.JPG", "DSC00099.JPG", "DSC00100.JPG", "DSC00101.JPG"]
    assert sorted(p.name for p in (tmp_path / "DCIM").iterdir()) == [p.name for p in paths]
    for path, rec in zip(paths, truth, strict=True):
        tags = tags_of(path)
        assert tags["Image Make"] == "SONY" and tags["Image Model"] == "ILCE-9"
        t = camera_time(clocks, rec.start_tau_s)
        assert tags["EXIF DateTimeOriginal"] == t.strftime("%Y:%m:%d %H:%M:%S")
        if resolution == "10ms":
            assert tags["EXIF SubSecTimeOriginal"] == f"{t.microsecond // 10_000:02d}"
        else:
            assert "EXIF SubSecTimeOriginal" not in tags
        assert read_frame_number(path) == rec.frame_number
        with Image.open(path) as img:
            assert img.format == "JPEG" and img.size == (64, 48)
    # the camera clock: local time 9 h ahead of UTC plus its 4.1 s error
    t1 = datetime.strptime(tags_of(paths[0])["EXIF DateTimeOriginal"], "%Y:%m:%d %H:%M:%S").replace(tzinfo=UTC)
    true_utc = datetime.fromtimestamp(UTC0_US / 1e6 + truth[0].start_tau_s, tz=UTC)
    assert (t1 - true_utc).total_seconds() == pytest.approx(32_404.1, abs=1.0)


def test_sub_second_digits_at_10_ms(tmp_path: Path) -> None:
    sc = load_scenario("deck_pass")  # 10 ms EXIF resolution
    clocks = ClockMaps.from_scenario(sc, 0, UTC0_US)
    truth = exposures(sc, clocks)
    paths = write_card(tmp_path, truth, clocks, sc.camera)
    assert paths[0].name == "DSC04512.JPG"
    subsecs = [tags_of(p)["EXIF SubSecTimeOriginal"] for p in paths]
    # 0.2 s between frames 1 and 2 shows in the digits (camera offset -1.87 s)
    first = int(subsecs[0])
    assert int(subsecs[1]) == (first + 20) % 100
    assert all(len(s) == 2 for s in subsecs)


def test_frames_without_exif_time(tmp_path: Path) -> None:
    sc = load_scenario("hover")
    clocks = ClockMaps.from_scenario(sc, 0, UTC0_US)
    paths = write_card(
        tmp_path, exposures(sc, clocks), clocks, Camera(make="Canon", model="EOS R5"), omit_exif_time={2}
    )
    tags = tags_of(paths[1])
    assert tags["Image Make"] == "Canon"
    assert not any("DateTime" in k or "SubSec" in k for k in tags)
    assert "EXIF DateTimeOriginal" in tags_of(paths[0])
    assert file_name(7) == "DSC00007.JPG"
