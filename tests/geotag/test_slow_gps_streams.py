"""A frame between two GPS samples that are further apart than the geotagger's wait (host bug, issue 9).

The position rules interpolate between GLOBAL_POSITION_INT samples up to `max_gps_gap_s` (1.5 s)
apart, but a frame is built once `max_wait_s` (0.5 s) has passed since its mid-exposure, whether
or not the later sample can still come. Real autopilots stream that slowly: ArduPilot's streams run
"4 or more times slower than requested while parameters are being sent"
(ardupilot.org/dev/docs/mavlink-requesting-data.html), so 4 Hz becomes 1 Hz during a parameter
download, and a 2 Hz stream puts the later sample 500 ms plus the link delay after the frame. The
simulator's ArduPilot profile (tests/e2e/profiles/ardupilot.toml, a parameter burst at 10 s) shows it
end to end: three frames between samples 1 s apart are labelled `vio` although GPS brackets them.
Right behaviour: while a later GPS sample is still due within the interpolation gap, the frame
waits for it and is then placed by GPS between the two.
"""

from __future__ import annotations

from test_geotagger import MID_US, ORIGIN, Rig, host_ns

from icgt.geotag.config import GeotagConfig


def test_a_frame_waits_for_the_later_gps_sample_of_a_1_hz_stream() -> None:
    rig = Rig(GeotagConfig(origin=ORIGIN))  # the recorder's defaults: max_wait 500 ms, max gap 1.5 s
    rig.gps(12_990)
    rig.pose(13_000)  # mid-exposure is at 13045 ms; the next sample of the 1 Hz stream is due at 14000 ms
    rig.expose()
    assert rig.poll(host_ns(MID_US) + 700_000_000) == []  # 700 ms later: the 14000 ms sample is still due
    rig.gps(13_990)
    rig.pose(14_000)
    out = rig.poll(host_ns(MID_US) + 960_000_000)
    assert len(out) == 1
    assert out[0].position_source == "gps_3d"
