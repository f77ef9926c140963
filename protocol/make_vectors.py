#!/usr/bin/env python3
"""Write the shared protocol test vectors (protocol/vectors/, SPEC.md §9).

    python protocol/make_vectors.py           # (re)write every vector
    python protocol/make_vectors.py --verify  # exit 1 if any file differs or is missing/extra

Each case is a byte stream (<case>.bin) and its expected canonical decoding (<case>.json).
The expected messages come from the values the case put in, not from decoding the bytes,
and the expected counters of invalid cases are written out by hand below, so a decoder that
disagrees with this file is wrong, whichever language it is in.
"""

from __future__ import annotations

import argparse
import random
import struct
import sys
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from pathlib import Path

from cobs import cobs

from icgt.protocol import messages as m
from icgt.protocol.canonical import STAT_KEYS, JsonValue, dumps

VECTORS = Path(__file__).resolve().parent / "vectors"

INT_RANGES = {
    "u8": (0, 2**8 - 1),
    "u16": (0, 2**16 - 1),
    "u32": (0, 2**32 - 1),
    "u64": (0, 2**64 - 1),
    "i8": (-(2**7), 2**7 - 1),
    "i16": (-(2**15), 2**15 - 1),
    "i32": (-(2**31), 2**31 - 1),
    "i64": (-(2**63), 2**63 - 1),
}


def raw_frame(
    msg_type: int,
    body: bytes,
    seq: int,
    *,
    version: int = m.PROTOCOL_VERSION,
    flags: int = 0,
    corrupt_crc: bool = False,
) -> bytes:
    """A wire frame built straight from the spec (not through the codec under test)."""
    raw = struct.pack("<BBBBI", version, msg_type, flags, 0, seq) + body
    crc = zlib.crc32(raw) ^ (0x00000100 if corrupt_crc else 0)
    return cobs.encode(raw + struct.pack("<I", crc)) + b"\x00"


def f32(x: float) -> float:
    return float(struct.unpack("<f", struct.pack("<f", x))[0])


def expected_fields(msg: m.Message) -> dict[str, JsonValue]:
    out: dict[str, JsonValue] = {}
    for name, wire_type in m.FIELD_TYPES[msg.NAME]:
        value = getattr(msg, name)
        out[name] = f32(value) if wire_type == "f32" else value
    return out


@dataclass
class Case:
    name: str
    valid: bool
    stream: bytearray = field(default_factory=bytearray)
    messages: list[dict[str, JsonValue]] = field(default_factory=list)
    stats: dict[str, int] = field(default_factory=dict)

    def add(self, msg: m.Message, seq: int, flags: int = 0) -> Case:
        self.stream += raw_frame(msg.ID, msg.body(), seq, flags=flags)
        self.messages.append({"type": msg.NAME, "seq": seq, "flags": flags, "fields": expected_fields(msg)})
        self.stats["frames_ok"] = self.stats.get("frames_ok", 0) + 1
        return self

    def junk(self, data: bytes, **counts: int) -> Case:
        self.stream += data
        for k, v in counts.items():
            self.stats[k] = self.stats.get(k, 0) + v
        return self

    def expected_json(self) -> str:
        stats: dict[str, JsonValue] = {k: self.stats.get(k, 0) for k in STAT_KEYS}
        stats["pending_bytes"] = self.stats.get("pending_bytes", 0)
        return dumps({"messages": list(self.messages), "stats": stats})


def edge_message(cls: type[m.Message], pick: Callable[[str, str], object]) -> m.Message:
    values = {f.name: pick(f.name, wire) for f, (_, wire) in zip(fields(cls), m.FIELD_TYPES[cls.NAME], strict=True)}
    return cls(**values)  # type: ignore[arg-type]


def pick_max(name: str, wire: str) -> object:
    if wire in INT_RANGES:
        return INT_RANGES[wire][1]
    if wire == "f32":
        return 3.4028234663852886e38
    if wire == "f64":
        return sys.float_info.max
    size = int(wire.split("[")[1].rstrip("]"))
    return ("é" * size)[: size // 2] if wire.startswith("str") else "Z" * size


def pick_min(name: str, wire: str) -> object:
    if wire in INT_RANGES:
        return INT_RANGES[wire][0]
    if wire == "f32":
        return -1.401298464324817e-45  # smallest-magnitude negative subnormal binary32
    if wire == "f64":
        return -sys.float_info.max
    return ""


def pick_special(name: str, wire: str) -> object:
    specials = [float("nan"), float("inf"), float("-inf"), -0.0]
    if wire in ("f32", "f64"):
        return specials[sum(map(ord, name)) % len(specials)]
    return pick_min(name, wire)


def typical_cases() -> list[Case]:
    cases = []
    t0 = 1_234_567_890
    examples: list[m.Message] = [
        m.Hello(
            protocol_version=m.PROTOCOL_VERSION,
            table_hash=m.TABLE_HASH,
            t_us=812,
            firmware_version="0.1.0+g1a2b3c",
            board=m.Board.TEENSY41,
            serial_number=8_675_309,
            clock_source=m.ClockSource.RTC,
            rtc_utc_us_at_boot=1_795_000_000_000_000,
            lidar_model=m.LidarModel.V3HP,
        ),
        m.Status(
            t_us=t0,
            capture_state=m.CaptureState.CAPTURING,
            sensor_health=0x1F,
            triggers_fired=120,
            exposures_confirmed=119,
            feedback_missing=1,
            messages_sent=70_000,
            dropped_imu=3,
            i2c_errors=2,
            imu_reinits=1,
            rx_frames_ok=40,
            rx_frames_rejected=1,
            loop_max_us=312,
        ),
        m.Exposure(
            image_index=17,
            camera_id=0,
            flags=0,
            trigger_t_us=t0,
            feedback_start_t_us=t0 + 48_211,
            feedback_end_t_us=t0 + 49_211,
            duration_us=1000,
            snapshot_flags=int(
                m.SnapshotFlags.RANGE_VALID | m.SnapshotFlags.RANGE_INTERPOLATED | m.SnapshotFlags.IMU_VALID
            ),
            range_mm=12_345,
            range_age_us=1_210,
            imu_age_us=4_870,
            imu_calib_stat=0xFF,
            quat_w_q14=11_585,
            quat_x_q14=-3,
            quat_y_q14=-11_585,
            quat_z_q14=16_384,
            gyro_x_rad900=-32_768,
            gyro_y_rad900=11,
            gyro_z_rad900=32_767,
        ),
        m.Imu(
            read_start_t_us=t0,
            read_end_t_us=t0 + 1210,
            quat_w=0.70710678,
            quat_x=0.0,
            quat_y=-0.70710678,
            quat_z=0.0,
            gyro_x_rad_s=0.0123,
            gyro_y_rad_s=-0.5,
            gyro_z_rad_s=1e-3,
            accel_x_m_s2=0.12,
            accel_y_m_s2=-0.03,
            accel_z_m_s2=9.81,
            lin_accel_x_m_s2=0.01,
            lin_accel_y_m_s2=0.0,
            lin_accel_z_m_s2=-0.02,
            calib_stat=0xFF,
            flags=m.ImuFlags.FUSION_RUNNING,
        ),
        m.Range(
            acq_start_t_us=t0,
            read_t_us=t0 + 1900,
            distance_cm=512,
            signal_strength=87,
            flags=m.RangeFlags.VALID | m.RangeFlags.BIAS_CORRECTED,
        ),
        m.Pps(t_us=t0, pps_count=42),
        m.TimeSyncReply(host_t_ns=1_795_000_000_123_456_789, request_seq=5, device_rx_t_us=t0, device_tx_t_us=t0 + 37),
        m.Ack(request_seq=9, request_type=m.MsgId.START_CAPTURE, error_code=m.ErrorCode.BUSY_CAPTURING, detail=0),
        m.Log(t_us=t0, level=m.LogLevel.WARNING, text='BNO055 NACK at 0x28, retry in 200 ms "\\ \t'),
        m.StartCapture(
            mode=m.CaptureMode.FOCUS_BURST,
            camera_id=0,
            interval_us=200_000,
            count=0,
            focus_lead_us=500_000,
            burst_us=2_000_000,
            shutter_pulse_us=20_000,
            host_timeout_ms=30_000,
        ),
        m.StopCapture(camera_id=0),
        m.Configure(
            imu_rate_hz=100,
            imu_mode=0x0C,
            imu_ext_crystal=1,
            range_rate_hz=500,
            lidar_model=m.LidarModel.V3,
            lidar_preset=0,
            lidar_bias_every=100,
            polarity=0x07,
            feedback_enabled=1,
            feedback_timeout_us=250_000,
        ),
        m.TimeSync(host_t_ns=1_795_000_000_123_456_789),
        m.SetTime(utc_us=1_795_000_000_250_000),
        m.Ping(nonce=0xDEADBEEF),
        m.Resend(first_seq=1000, count=16),
        m.ResendLost(first_seq=1000, count=16, resent=9, exposures=1, pps=0, samples=4, other=2, unknown=0),
        m.DeviceState(
            t_us=t0,
            capture_state=m.CaptureState.CAPTURING,
            mode=m.CaptureMode.INTERVAL,
            interval_us=200_000,
            count=0,
            focus_lead_us=0,
            burst_us=0,
            shutter_pulse_us=20_000,
            triggers_fired=311,
            capture_start_seq=4_000,
            next_seq=95_123,
            history_first_seq=0,
            host_received_seq=94_000,
            host_received_valid=1,
            imu_rate_hz=100,
            range_rate_hz=200,
            lidar_model=m.LidarModel.V3,
            polarity=0x0B,
            feedback_enabled=1,
            feedback_timeout_us=150_000,
            host_timeout_ms=30_000,
            stop_cause=m.StopCause.NONE,
            stopped_t_us=0,
            recording_id=0x5EED1234,
        ),
        m.HostReceived(next_seq=94_000, recording_id=0x5EED1234),
    ]
    covered = {type(x) for x in examples}
    missing = set(m.MESSAGE_TYPES.values()) - covered
    if missing:
        raise SystemExit(f"make_vectors.py: no typical example for {sorted(c.NAME for c in missing)}")
    for i, msg in enumerate(examples):
        cases.append(Case(f"{msg.NAME.lower()}_typical", True).add(msg, seq=i))
    for cls in m.MESSAGE_TYPES.values():
        name = cls.NAME.lower()
        cases.append(Case(f"{name}_max", True).add(edge_message(cls, pick_max), seq=0xFFFFFFFF))
        cases.append(Case(f"{name}_min", True).add(edge_message(cls, pick_min), seq=0))
        if any(w in ("f32", "f64") for _, w in m.FIELD_TYPES[cls.NAME]):
            cases.append(Case(f"{name}_nan_inf", True).add(edge_message(cls, pick_special), seq=1))
    longest = "ok " + "Ω" * 98 + "!"  # 3 + 196 + 1 = 200 bytes of UTF-8
    assert len(longest.encode()) == 200
    cases.append(Case("log_max_length_text", True).add(m.Log(t_us=1, level=m.LogLevel.ERROR, text=longest), seq=3))
    cases.append(
        Case("log_control_characters", True).add(m.Log(t_us=2, level=1, text='a\x01b\x1fc\x7fd\ne"f\\'), seq=4)
    )
    cases.append(Case("hello_full_length_version", True).add(m.Hello(firmware_version="1234567890abcdef"), seq=0))
    return cases


def stream_cases() -> list[Case]:
    rng = random.Random(20261121)
    cases = []

    mixed = Case("mixed_stream", True)
    seq = 0
    for k in range(40):
        t = 1_000_000 + k * 2000
        mixed.add(
            m.Range(
                acq_start_t_us=t, read_t_us=t + 1500, distance_cm=400 + k, signal_strength=90, flags=m.RangeFlags.VALID
            ),
            seq,
        )
        seq += 1
        if k % 5 == 0:
            mixed.add(
                m.Imu(read_start_t_us=t, read_end_t_us=t + 900, quat_w=1.0, accel_z_m_s2=9.80665, calib_stat=0x3F), seq
            )
            seq += 1
        if k % 20 == 0:
            mixed.add(
                m.Exposure(
                    image_index=1 + k // 20,
                    trigger_t_us=t,
                    feedback_start_t_us=t + 40_000,
                    feedback_end_t_us=t + 41_000,
                    duration_us=1000,
                ),
                seq,
            )
            seq += 1
    cases.append(mixed)

    idle = Case("idle_delimiters_between_frames", True).junk(b"\x00\x00\x00")
    idle.add(m.Ping(nonce=1), 0).junk(b"\x00" * 5).add(m.Ping(nonce=2), 1).junk(b"\x00")
    cases.append(idle)

    gap = Case("sequence_gap", True).add(m.Ping(nonce=1), 10).add(m.Ping(nonce=2), 11).add(m.Ping(nonce=3), 15)
    gap.stats.update(seq_gaps=1, seq_missed=3)
    cases.append(gap)

    wrap = Case("sequence_wraps", True)
    for s in (0xFFFFFFFE, 0xFFFFFFFF, 0, 1):
        wrap.add(m.Ping(nonce=s), s)
    cases.append(wrap)

    reset = Case("sequence_reset_after_reboot", True).add(m.Ping(nonce=1), 500).add(m.Ping(nonce=2), 0)
    reset.stats.update(seq_resets=1)
    cases.append(reset)

    retx = Case("retransmit_keeps_expectation", True).add(m.Ping(nonce=1), 20)
    retx.add(m.Ping(nonce=2), 7, flags=m.FrameFlags.RETRANSMIT).add(m.Ping(nonce=3), 21)
    cases.append(retx)

    # A device's answer to RESEND(first_seq=102, count=4) after a gap of 102..105: two frames come back
    # flagged retransmit with their original seq (moving no expectation), the rest is counted gone.
    retx_flag = m.FrameFlags.RETRANSMIT
    answer = Case("resend_answer", True)
    t = 5_000_000
    answer.add(m.Pps(t_us=t, pps_count=5), 100).add(m.Range(acq_start_t_us=t + 10, read_t_us=t + 20), 101)
    answer.add(m.Imu(read_start_t_us=t + 900, read_end_t_us=t + 1900, quat_w=1.0), 106)
    answer.add(
        m.Exposure(image_index=31, trigger_t_us=t + 100, feedback_start_t_us=t + 140, feedback_end_t_us=t + 150),
        102,
        flags=retx_flag,
    )
    answer.add(m.Pps(t_us=t + 1_000_000, pps_count=6), 104, flags=retx_flag)
    answer.add(m.ResendLost(first_seq=102, count=4, resent=2, samples=1, other=1), 107)
    answer.add(m.Range(acq_start_t_us=t + 2000, read_t_us=t + 2100), 108)
    answer.stats.update(seq_gaps=1, seq_missed=4)
    cases.append(answer)

    # Retransmits of a range older than everything live, one of them with the other flag bits set too.
    old_retx = Case("retransmit_from_the_past", True).add(m.HostReceived(next_seq=0), 50)
    old_retx.add(m.Exposure(image_index=2, trigger_t_us=10), 3, flags=retx_flag | 0x80)
    old_retx.add(m.Exposure(image_index=3, trigger_t_us=20), 4, flags=retx_flag).add(m.Ping(nonce=9), 51)
    cases.append(old_retx)

    reserved_flags = Case("unassigned_flag_bits_ignored", True).add(m.Ping(nonce=5), 0, flags=0xFE)
    cases.append(reserved_flags)

    # --- invalid inputs: each rejected frame is followed by a valid one that must decode
    def then_ping(case: Case, seq: int = 0) -> Case:
        return case.add(m.Ping(nonce=0x1234), seq)

    ping_body = m.Ping(nonce=7).body()
    cases.append(
        then_ping(Case("bad_crc", False).junk(raw_frame(m.Ping.ID, ping_body, 0, corrupt_crc=True), crc_error=1), 1)
    )
    cases.append(then_ping(Case("truncated_frame", False).junk(cobs.encode(b"\x01\x45\x00") + b"\x00", truncated=1)))
    cases.append(then_ping(Case("oversized_frame", False).junk(bytes([0x42]) * 300 + b"\x00", oversized=1)))
    cases.append(then_ping(Case("oversized_by_one_byte", False).junk(bytes([0xFF]) * 259 + b"\x00", oversized=1)))
    cases.append(then_ping(Case("cobs_code_past_end", False).junk(b"\x09\x01\x02\x00", cobs_error=1)))
    junk = bytes(rng.randrange(1, 256) for _ in range(57))
    cases.append(then_ping(Case("junk_before_first_frame", False).junk(junk + b"\x00", **_classify_junk(junk))))
    short_junk = bytes(rng.randrange(1, 256) for _ in range(3))
    between = Case("junk_between_frames", False).add(m.Ping(nonce=1), 0)
    between.junk(short_junk + b"\x00", **_classify_junk(short_junk))
    cases.append(then_ping(between, 1))
    cases.append(then_ping(Case("unknown_type", False).junk(raw_frame(0x3E, b"", 0), unknown_type=1), 1))
    cases.append(then_ping(Case("type_zero", False).junk(raw_frame(0x00, b"", 0), unknown_type=1), 1))
    cases.append(
        then_ping(
            Case("wrong_version", False).junk(
                raw_frame(m.Ping.ID, ping_body, 0, version=m.PROTOCOL_VERSION + 1), wrong_version=1
            ),
            1,
        )
    )
    # A version-1 device's EXPOSURE (34 bytes, no sensor snapshot): refused on its header's version.
    v1_exposure = struct.pack("<IBBQQQI", 5, 0, 0, 1_000_000, 1_048_000, 1_049_000, 1000)
    cases.append(
        then_ping(
            Case("version_1_exposure", False).junk(
                raw_frame(m.Exposure.ID, v1_exposure, 0, version=1), wrong_version=1
            ),
            1,
        )
    )
    cases.append(
        then_ping(Case("body_too_long", False).junk(raw_frame(m.Ping.ID, ping_body + b"\x01", 0), bad_length=1), 1)
    )
    cases.append(
        then_ping(Case("body_too_short", False).junk(raw_frame(m.Exposure.ID, b"\x01" * 10, 0), bad_length=1), 1)
    )
    too_long_log = m.Log(t_us=1, level=1).body() + b"x" * 201
    cases.append(
        then_ping(Case("log_text_too_long", False).junk(raw_frame(m.Log.ID, too_long_log, 0), bad_length=1), 1)
    )
    unterminated = then_ping(Case("unterminated_tail_is_pending", False))
    tail = raw_frame(m.Ping.ID, ping_body, 1)[:-1]
    unterminated.junk(tail, pending_bytes=len(tail))
    cases.append(unterminated)
    return cases


def _classify_junk(junk: bytes) -> dict[str, int]:
    """Expected counter for a junk run, decided from the spec's rules, not by the codec."""
    if len(junk) > 258:
        return {"oversized": 1}
    try:
        raw = cobs.decode(junk)
    except cobs.DecodeError:
        return {"cobs_error": 1}
    if len(raw) < 12:
        return {"truncated": 1}
    return {"crc_error": 1}  # a random run passing the CRC has probability 2^-32; checked below


def all_cases() -> list[Case]:
    cases = typical_cases() + stream_cases()
    names = [c.name for c in cases]
    dupes = {n for n in names if names.count(n) > 1}
    if dupes:
        raise SystemExit(f"make_vectors.py: duplicate case names {sorted(dupes)}")
    return cases


def render() -> dict[Path, bytes]:
    files: dict[Path, bytes] = {}
    for case in all_cases():
        folder = VECTORS / ("valid" if case.valid else "invalid")
        files[folder / f"{case.name}.bin"] = bytes(case.stream)
        files[folder / f"{case.name}.json"] = (case.expected_json() + "\n").encode()
    return files


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="write or verify the protocol test vectors")
    parser.add_argument("--verify", action="store_true", help="fail if any vector file is stale")
    args = parser.parse_args(argv)
    files = render()
    existing = {p for p in VECTORS.glob("*/*") if p.suffix in (".bin", ".json")}
    if args.verify:
        problems = [
            f"stale: {p.relative_to(VECTORS)}" for p, data in files.items() if not p.exists() or p.read_bytes() != data
        ]
        problems += [f"not generated (delete it): {p.relative_to(VECTORS)}" for p in existing - set(files)]
        for line in problems:
            print(line, file=sys.stderr)
        if problems:
            print("run: python protocol/make_vectors.py", file=sys.stderr)
            return 1
        print(f"{len(files) // 2} vectors up to date")
        return 0
    for p in existing - set(files):
        p.unlink()
    for p, data in files.items():
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(data)
    print(f"wrote {len(files) // 2} vectors to {VECTORS}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
