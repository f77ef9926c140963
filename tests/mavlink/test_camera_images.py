"""Units of the camera's image policy: request ranges, the poor-pose verdict, height above home, throttled logs."""

from __future__ import annotations

import logging

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from icgt.geotag.record import POOR_POSE_FLAGS
from icgt.mapping.cli import UNTRUSTED_POSE
from icgt.mavlink.camera_images import image_range
from icgt.mavlink.home import HomeAltitude
from icgt.mavlink.ratelimit import ThrottledLog, TokenBucket
from icgt.recorder.camera_link import pose_verdict


@pytest.mark.parametrize(
    "first, last, count, want",
    [
        (0, 0, 5, [0]),
        (3, 0, 5, [3]),
        (-1, 0, 5, [0, 1, 2, 3, 4]),  # all
        (-1, 7, 5, [0, 1, 2, 3, 4]),  # all, whatever param3 says
        (2, -1, 5, [2, 3, 4]),  # this and every later one
        (1, 3, 5, [1, 2, 3]),  # a range
        (3, 99, 5, [3, 4]),  # a range past the newest: up to the newest
    ],
)
def test_image_ranges(first, last, count, want):
    got, why = image_range(first, last, count)
    assert list(got) == want and why == ""


@pytest.mark.parametrize(
    "first, last, count, why",
    [
        (5, 0, 5, "not taken yet"),
        (0, 0, 0, "no images yet"),
        (3, 1, 5, "empty"),
        (1.5, 0, 5, "param2"),
        (-2, 0, 5, "param2"),
        (0, float("nan"), 5, "param3"),
    ],
)
def test_impossible_ranges_say_why(first, last, count, why):
    got, reason = image_range(first, last, count)
    assert list(got) == [] and why in reason


def test_poor_pose_flags_are_the_ones_the_damage_map_distrusts():
    assert set(POOR_POSE_FLAGS) == set(UNTRUSTED_POSE)


def test_pose_verdicts():
    assert pose_verdict([]) == (True, True, "good")
    assert pose_verdict(["clock_unsynced", "range_invalid"])[:2] == (True, True)
    ok, position, why = pose_verdict(["stale_pose", "pose_extrapolated"])
    assert (ok, position) == (False, False) and "stale_pose" in why and "pose_extrapolated" in why
    ok, position, why = pose_verdict(["feedback_missing"])
    assert (ok, position) == (False, True) and "feedback_missing" in why
    # a frame left without a position (no pose between distant samples, telemetry gone) publishes none
    for flag in ("no_pose", "telemetry_expired", "no_fix"):
        ok, position, why = pose_verdict([flag])
        assert (ok, position) == (False, False) and flag in why


def gpi(alt_m, rel_m, lat=473977419, lon=85455000):
    return mavlink2.MAVLink_global_position_int_message(0, lat, lon, round(alt_m * 1e3), round(rel_m * 1e3), 0, 0, 0, 0)


def test_home_altitude_is_interpolated_and_ignores_samples_without_a_fix():
    home = HomeAltitude()
    assert home.relative_alt_m(100.0, 0) is None
    home.on_global_position(gpi(0.0, 8.0, lat=0, lon=0), 0)  # no fix yet: ignored
    assert home.home_alt_msl_m(0) is None
    home.on_global_position(gpi(108.3, 8.3), 1_000_000_000)  # home at 100.0 m MSL
    home.on_global_position(gpi(110.3, 8.3), 2_000_000_000)  # home reset to 102.0 m
    assert home.home_alt_msl_m(500_000_000) == pytest.approx(100.0)  # before the first: the first
    assert home.home_alt_msl_m(1_500_000_000) == pytest.approx(101.0)
    assert home.relative_alt_m(109.0, 1_250_000_000) == pytest.approx(8.5)
    assert home.home_alt_msl_m(9_000_000_000) == pytest.approx(102.0)


def test_token_bucket():
    bucket = TokenBucket(5.0, 5)
    assert sum(bucket.allow(0) for _ in range(20)) == 5
    assert bucket.allow(200_000_000)  # one more token after 0.2 s
    assert not bucket.allow(200_000_000)


def test_throttled_log_counts_what_it_does_not_print(caplog):
    t = ThrottledLog(logging.getLogger("icgt.test"), "refused", period_s=1.0)
    with caplog.at_level(logging.WARNING, logger="icgt.test"):
        for i in range(100):
            t.report(i * 1_000_000, f"#{i}")  # 100 in 0.1 s
        assert len(caplog.records) == 1
        t.tick(500_000_000)
        assert len(caplog.records) == 1  # within the period
        t.tick(1_100_000_000)
        assert len(caplog.records) == 2 and "99 since the last report (100 in total)" in caplog.records[1].getMessage()
        t.flush()
        assert len(caplog.records) == 2  # nothing pending
    assert t.total == 100
