"""Issue 27 end to end: a 30 s USB unplug costs the recovered frames nothing the host can keep.

The real firmware core behind the simulator's pty, `icgt record` as a subprocess (`icgt.sim.outage_flight`): a
hover at 5 fps with IMU and range at 100 Hz and the fused position at 50 Hz, the cable pulled at 8 s for 30 s, the
capture running until 10 s after it is back. The flight's live frames (before and after the unplug) are the flight
without the unplug: every exposure the unplug covered comes back through RESEND and is posed as they are (geotag
error against the simulator's truth: RMS as theirs, none beyond the fused position's noise), because the host kept
the autopilot telemetry that arrived on time. Every one is ranged as the live ones are (`RANGE_MARGIN_M`):
the frames of the last seconds of the unplug from the LiDAR samples the device still held (its range ring: 1024
samples, 10.2 s at 100 Hz), the older ones, whose samples are gone, from the range the device recorded with the
exposure itself (its sensor snapshot, protocol 2: `range_from_snapshot`, range source `snapshot`), interpolated
between the same acquisitions the host would have used.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from replay_check import assert_replay_reproduces_every_frame

from icgt.sim.outage_flight import UNPLUG_AT_S, OutageFlight, fly_outage
from icgt.sim.scenario import load_scenario

SCENARIO = Path(__file__).with_name("resend_flight.toml")
UNPLUG_S = 30.0
POSITION_RMS_MARGIN_M = 0.01  # the recovered frames' geotag error RMS: at most 1.3 x the live frames' plus this
RANGE_MARGIN_M = 0.005  # recovered ranges: the margin on their error RMS (1.3 x the live frames' or 1.3 sigma) [m]
SAMPLES_HELD_S = 10.2  # the device's range ring at 100 Hz: older frames can only be ranged from the snapshot

pytestmark = pytest.mark.timeout(300)


def _rms(errors_m: list[float | None] | np.ndarray) -> float:
    """Root mean square of errors [m] (every one present)."""
    return float(np.sqrt(np.mean(np.asarray(errors_m, dtype=float) ** 2)))


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> OutageFlight:
    return fly_outage(load_scenario(SCENARIO), UNPLUG_S, tmp_path_factory.mktemp("outage"))


def test_every_exposure_of_the_unplug_came_back_as_a_resent_frame(flight: OutageFlight) -> None:
    made = flight.exposures_between(UNPLUG_AT_S, UNPLUG_AT_S + UNPLUG_S)
    frames = flight.window(True)
    assert made >= 140 and len(frames) == made  # 5 fps for 30 s
    assert sum(f.resent for f in frames) >= made - 10  # all but the last second's come through RESEND
    # none from before the unplug, none from after the reconnect (those made while it reconnected: resent too)
    reconnected_s = UNPLUG_AT_S + UNPLUG_S + 3.0
    assert not any(f.resent for f in flight.frames if f.start_s < UNPLUG_AT_S or f.start_s > reconnected_s)


def test_every_recovered_frame_is_posed_as_the_live_ones_are(flight: OutageFlight) -> None:
    live = [f.geotag_error_m for f in flight.window(False)]
    assert len(live) >= 50 and all(e is not None for e in live)
    recovered = flight.window(True)
    for f in recovered:
        assert f.geotag_error_m is not None, f"frame {f.image_index} has no position: {f.flags}"
        assert "telemetry_expired" not in f.flags
    # Posed as the live ones are: the same error distribution, and no frame beyond the fused position's noise.
    # (Not "within the live frames' worst plus 5 cm": the worst of ~150 recovered frames against the worst of
    # ~55 live ones is a draw of the noise; CI met 0.135 m against 0.083 m once.) A pose held or taken at the
    # wrong time would be off by the sway's 0.3 m, a distribution shift the RMS sees.
    gps = load_scenario(SCENARIO).gps
    sigma_m = float(np.sqrt(2.0 * gps.fused_noise_horizontal_m**2 + gps.fused_noise_vertical_m**2))  # 3-D RMS
    rec_err = np.array([f.geotag_error_m for f in recovered], dtype=float)
    assert _rms(rec_err) <= 1.3 * _rms(live) + POSITION_RMS_MARGIN_M, (_rms(rec_err), _rms(live))
    assert float(rec_err.max()) <= 5.0 * sigma_m, (float(rec_err.max()), sigma_m)


def test_every_recovered_frame_is_ranged_as_the_live_ones_from_the_samples_or_its_own_snapshot(
    flight: OutageFlight,
) -> None:
    live = [f.range_error_m for f in flight.window(False) if f.true_range]
    assert live and all(e is not None for e in live)
    back_s = UNPLUG_AT_S + UNPLUG_S
    # Frames away from the outage's edges have their range samples: the snapshot never stands in. (A frame
    # made just before the unplug can lose the samples after its mid with the cable, and one made while the
    # link came back gets them only through RESEND: for those the snapshot is what it is for.)
    untouched = [f for f in flight.window(False) if f.start_s < UNPLUG_AT_S - 1.0 or f.start_s > back_s + 3.0]
    assert len(untouched) >= 40
    snapped = [(f.image_index, round(f.start_s, 2)) for f in untouched if "range_from_snapshot" in f.flags]
    assert not snapped, f"live frames away from the outage ranged from their snapshot: {snapped}"
    recovered = flight.window(True)
    for f in recovered:
        assert f.true_range
        assert f.range_error_m is not None, f"frame {f.image_index} at {f.start_s:.1f} s unranged: {f.flags}"
        assert "range_samples_lost" not in f.flags and "range_invalid" not in f.flags
    sigma_m = load_scenario(SCENARIO).sensors.range_noise_cm / 100.0
    # Interpolated from the samples, as the live ones are: the same error distribution (RMS within 1.3 x theirs
    # plus RANGE_MARGIN_M), none beyond 5 sigma of the sensor's noise. (Not "within the live frames' worst plus
    # 2 cm": the worst of ~50 noise draws against the worst of ~55; CI met 6.9 cm against 4.6 cm once.)
    interp = np.array([f.range_error_m for f in recovered if "range_from_snapshot" not in f.flags], dtype=float)
    assert interp.size >= 20, interp
    assert _rms(interp) <= 1.3 * _rms(live) + RANGE_MARGIN_M, (interp, _rms(live))
    assert float(interp.max()) <= 5.0 * sigma_m, (interp, sigma_m)
    from_snapshot = [f for f in recovered if "range_from_snapshot" in f.flags]
    # A snapshot is one reading, not two interpolated: its error is the sensor's noise (the live frames' worst
    # is not its bound: under load the readings an exposure meets differ, and 1 of 100 single readings beyond
    # 2.2 sigma is expected). Bounded by the noise model instead: RMS within 1.3 sigma, none beyond 5 sigma.
    snap_err = np.array([f.range_error_m for f in from_snapshot], dtype=float)
    assert snap_err.size and _rms(snap_err) <= 1.3 * sigma_m + RANGE_MARGIN_M, snap_err
    assert float(snap_err.max()) <= 5.0 * sigma_m + RANGE_MARGIN_M, snap_err
    # the samples of the unplug's first 20 s had left the device's ring: only the snapshot ranges those
    older = [f for f in recovered if f.start_s < back_s - SAMPLES_HELD_S - 2.0]
    assert len(older) >= 80 and all(f in from_snapshot for f in older)


def test_the_recompute_gives_back_every_frame_with_its_flags(flight: OutageFlight) -> None:
    # One synchroniser, one telemetry retention: recomputed from the log, the resent frames come out as live.
    (recording,) = flight.result.recordings
    assert assert_replay_reproduces_every_frame(recording) >= len(flight.frames)
