"""Packed telemetry samples (icgt.mavlink.sample_codec): exact round trips of every sample type, None kept
apart from every value, and the memory a held sample takes (the figure `TelemetryStore.memory_bytes` uses)."""

from __future__ import annotations

import dataclasses
import gc
import math
import tracemalloc
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from icgt.mavlink.sample_codec import PACKED_SAMPLE_BYTES, SampleCodec
from icgt.mavlink.telemetry import (
    AttitudeSample,
    FusedPositionSample,
    GpsSample,
    LocalPositionSample,
    SystemTimeSample,
    TelemetryBuffer,
    TelemetryStore,
)

ints = st.integers(-(2**63), 2**63 - 1)
floats = st.floats(allow_nan=False)  # NaN != NaN: its bits round trip too, but equality cannot show it


def _maybe(s: st.SearchStrategy[Any]) -> st.SearchStrategy[Any]:
    return st.none() | s


gps = st.builds(
    GpsSample,
    boot_us=ints, host_rx_ns=ints, fix_type=ints, usable=st.booleans(), lat_deg=_maybe(floats),
    lon_deg=_maybe(floats), alt_msl_m=_maybe(floats), alt_ellipsoid_m=_maybe(floats), raw_lat_e7=ints,
    raw_lon_e7=ints, raw_alt_mm=ints, h_acc_m=_maybe(floats), v_acc_m=_maybe(floats), vel_acc_mps=_maybe(floats),
    eph=_maybe(floats), epv=_maybe(floats), vel_mps=_maybe(floats), cog_deg=_maybe(floats),
    satellites=_maybe(ints), yaw_deg=_maybe(floats),
)  # fmt: skip
fused = st.builds(
    FusedPositionSample,
    boot_us=ints, host_rx_ns=ints, usable=st.booleans(), lat_deg=_maybe(floats), lon_deg=_maybe(floats),
    alt_msl_m=_maybe(floats), relative_alt_m=floats, raw_lat_e7=ints, raw_lon_e7=ints, raw_alt_mm=ints,
    vn_mps=floats, ve_mps=floats, vd_mps=floats, heading_deg=_maybe(floats),
)  # fmt: skip
attitude = st.builds(
    AttitudeSample,
    boot_us=ints, host_rx_ns=ints, q_wxyz=st.tuples(floats, floats, floats, floats), roll_rad=floats,
    pitch_rad=floats, yaw_rad=floats, rollspeed_rps=floats, pitchspeed_rps=floats, yawspeed_rps=floats,
    source=st.sampled_from(["ATTITUDE", "ATTITUDE_QUATERNION"]),
)  # fmt: skip
local = st.builds(LocalPositionSample, ints, ints, floats, floats, floats, floats, floats, floats, ints)
system_time = st.builds(SystemTimeSample, ints, ints, ints, _maybe(ints))

CODECS = {cls: SampleCodec(cls) for cls in (GpsSample, FusedPositionSample, AttitudeSample, LocalPositionSample)}
CODECS[SystemTimeSample] = SampleCodec(SystemTimeSample)


@given(st.one_of(gps, fused, attitude, local, system_time))
def test_every_sample_type_round_trips_exactly(sample: Any) -> None:
    codec = CODECS[type(sample)]
    back = codec.decode(codec.encode(sample))
    assert back == sample
    for f in dataclasses.fields(sample):  # 0.0 and -0.0 compare equal: their signs must survive too
        a, b = getattr(sample, f.name), getattr(back, f.name)
        if isinstance(a, float):
            assert math.copysign(1.0, a) == math.copysign(1.0, b)


def test_none_and_zero_stay_apart() -> None:
    codec = CODECS[GpsSample]
    base = GpsSample(1, 2, 3, True, 0.0, 0.0, 0.0, None, 0, 0, 0, None, 0.0, None, None, None, None, None, 0, None)
    back = codec.decode(codec.encode(base))
    assert back.alt_ellipsoid_m is None and back.lat_deg == 0.0 and back.satellites == 0 and back.h_acc_m is None


def test_types_that_do_not_pack_are_refused_when_the_codec_is_made() -> None:
    @dataclasses.dataclass(frozen=True)
    class Odd:
        boot_us: int
        tags: list[int]

    with pytest.raises(TypeError, match="tags"):
        SampleCodec(Odd)


def _held_bytes(make: Any, n: int) -> float:
    """Bytes per sample a packed TelemetryBuffer holds, by tracemalloc (the buffer's own allocations)."""
    gc.collect()
    tracemalloc.start()
    try:
        buf: TelemetryBuffer[Any] = TelemetryBuffer(n + 1, codec=SampleCodec(type(make(0))))
        base = tracemalloc.get_traced_memory()[0]
        for k in range(n):
            buf.push(make(k))
        gc.collect()
        return (tracemalloc.get_traced_memory()[0] - base) / n
    finally:
        tracemalloc.stop()


def test_a_held_sample_takes_at_most_the_stated_memory() -> None:
    def gps_at(k: int) -> GpsSample:
        return GpsSample(
            k * 200_000, k * 199_999_000, 3, True, 47.0 + k * 1e-9, 8.0, 500.0, 548.0, 470_000_000, 80_000_000,
            500_000, 0.8, 1.2, 0.3, 0.9, 1.4, 12.5, 181.0, 14, None,
        )  # fmt: skip

    def fused_at(k: int) -> FusedPositionSample:
        return FusedPositionSample(
            k * 20_000, k * 19_999_000, True, 47.0, 8.0, 500.0, 30.0, 470_000_000, 80_000_000, 500_000,
            1.0 + k * 1e-6, 2.0, -0.1, 90.0,
        )  # fmt: skip

    def attitude_at(k: int) -> AttitudeSample:
        return AttitudeSample(k * 20_000, k * 19_999_000, (1.0, 0.0, 0.0, k * 1e-9), 0.1, 0.2, 0.3, 0, 0, 0, "ATTITUDE")

    for make in (gps_at, fused_at, attitude_at):
        per_sample = _held_bytes(make, 20_000)
        assert per_sample <= PACKED_SAMPLE_BYTES, (make.__name__, per_sample)
        # and far below the dataclass objects' 500-650 B that the soak measured (issue 30)
        assert per_sample < 300


def test_the_store_packs_its_streams_and_gives_back_what_went_in() -> None:
    store = TelemetryStore(retention_s=10.0)
    samples = [
        FusedPositionSample(k * 20_000, k, k % 2 == 0, None, None, None, 1.0, 0, 0, 0, 0.5, 0.25, 0.0, None)
        for k in range(10)
    ]
    for s in samples:
        store.fused.push(s)
    assert store.fused.samples() == samples
    assert store.fused.between(40_000, 80_000) == samples[2:5]
    assert store.fused.bracket(50_000) == (samples[2], samples[3])
    assert store.fused.latest() == samples[-1] and store.fused.oldest() == samples[0]
