#!/usr/bin/env python3
"""Benchmark: Python decode throughput of the ICGT protocol against pymavlink, same run.

    make bench            (or: .venv/bin/python benchmarks/protocol_decode.py)

The ICGT stream is what a capture sends per second: 5 exposures, 100 IMU samples, 500
range samples, 1 status. The peer is pymavlink's MAVLink.parse_buffer on the same number
of MAVLink 2 GPS_RAW_INT messages (the autopilot's own telemetry decoder). Both decode
from an in-memory buffer in 4 KiB reads, as a serial reader would hand them over; the
best of several repeats is printed, because these machines are shared and noisy.
"""

from __future__ import annotations

import argparse
import time

from pymavlink.dialects.v20 import common as mavlink2

from icgt.protocol import StreamDecoder, encode_frame
from icgt.protocol.messages import Exposure, Imu, Range, Status

TARGET_RATIO = 5.0


def icgt_stream(seconds: int) -> tuple[bytes, int]:
    frames: list[bytes] = []
    seq = 0
    for s in range(seconds):
        base = 10_000_000 + s * 1_000_000
        for k in range(500):
            t = base + k * 2000
            frames.append(
                encode_frame(
                    Range(acq_start_t_us=t, read_t_us=t + 1800, distance_cm=512 + k % 7, signal_strength=80, flags=1),
                    seq,
                )
            )
            seq += 1
            if k % 5 == 0:
                frames.append(
                    encode_frame(
                        Imu(
                            read_start_t_us=t,
                            read_end_t_us=t + 950,
                            quat_w=0.99,
                            quat_x=0.01,
                            quat_y=0.02,
                            quat_z=0.1,
                            gyro_z_rad_s=0.01,
                            accel_z_m_s2=9.81,
                            calib_stat=0xFF,
                            flags=1,
                        ),
                        seq,
                    )
                )
                seq += 1
            if k % 100 == 0:
                frames.append(
                    encode_frame(
                        Exposure(
                            image_index=seq,
                            trigger_t_us=t,
                            feedback_start_t_us=t + 40_000,
                            feedback_end_t_us=t + 41_000,
                            duration_us=1000,
                        ),
                        seq,
                    )
                )
                seq += 1
        frames.append(encode_frame(Status(t_us=base, capture_state=1, triggers_fired=s * 5), seq))
        seq += 1
    return b"".join(frames), seq


def mavlink_stream(count: int) -> bytes:
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    out = bytearray()
    for i in range(count):
        msg = mav.gps_raw_int_encode(
            i * 200_000,
            3,
            473_977_418,
            85_455_938,
            488_000,
            120,
            150,
            800,
            9000,
            14,
            alt_ellipsoid=536_000,
            h_acc=900,
            v_acc=1500,
            vel_acc=200,
            hdg_acc=0,
            yaw=0,
        )
        out += msg.pack(mav)
    return bytes(out)


def time_icgt(data: bytes, expected: int) -> float:
    dec = StreamDecoder()
    n = 0
    start = time.perf_counter()
    for i in range(0, len(data), 4096):
        n += len(dec.feed(data[i : i + 4096]))
    elapsed = time.perf_counter() - start
    if n != expected or dec.stats.rejected:
        raise SystemExit(f"icgt decoder returned {n} of {expected} messages, {dec.stats}")
    return elapsed


def time_pymavlink(data: bytes, expected: int) -> float:
    mav = mavlink2.MAVLink(None)
    n = 0
    start = time.perf_counter()
    for i in range(0, len(data), 4096):
        got = mav.parse_buffer(data[i : i + 4096])
        if got:
            n += len(got)
    elapsed = time.perf_counter() - start
    if n != expected:
        raise SystemExit(f"pymavlink returned {n} of {expected} messages")
    return elapsed


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=int, default=200, help="seconds of capture traffic to decode")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    data, count = icgt_stream(args.seconds)
    mav = mavlink_stream(count)
    t_icgt = min(time_icgt(data, count) for _ in range(args.repeats))
    t_mav = min(time_pymavlink(mav, count) for _ in range(args.repeats))
    icgt_rate, mav_rate = count / t_icgt, count / t_mav
    ratio = icgt_rate / mav_rate
    print(
        f"messages per run: {count} (ICGT mixed capture stream, {len(data) / count:.1f} B/msg; "
        f"MAVLink2 GPS_RAW_INT {len(mav) / count:.1f} B/msg)"
    )
    print(f"icgt StreamDecoder.feed : {icgt_rate:10.0f} msg/s  {len(data) / t_icgt / 1e6:6.2f} MB/s")
    print(f"pymavlink parse_buffer  : {mav_rate:10.0f} msg/s  {len(mav) / t_mav / 1e6:6.2f} MB/s")
    print(
        f"ratio icgt/pymavlink    : {ratio:.1f}x (target >= {TARGET_RATIO:.0f}x) "
        f"{'OK' if ratio >= TARGET_RATIO else 'BELOW TARGET'}"
    )
    print(f"link-rate headroom      : {icgt_rate / 606:.0f}x the nominal 606 msg/s capture stream")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
