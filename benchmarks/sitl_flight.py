#!/usr/bin/env python3
"""Benchmark: `icgt record` on a flight of the real autopilot firmware (ArduCopter SITL), issue 29.1.

    .venv/bin/python benchmarks/sitl_flight.py --ardupilot PATH/arducopter [--px4 PATH] [--out DIR]

Starts the ArduCopter SITL binary (built from ArduPilot's public sources, docs/sitl.md), our simulated
device (icgt-sim-device, for the camera's exposures) and `icgt record` on the SITL's SERIAL1 (TCP 5762).
This script is the ground station on SERIAL0 (TCP 5760, system 255): it uploads with pymavlink a mission
(take-off, a horizontal line with DO_SET_CAM_TRIGG_DIST, a vertical scan line with a time trigger
(mission IMAGE_START_CAPTURE with an interval), land) and flies it in AUTO. ArduPilot's MAVLink camera
backend (CAM1_TYPE = 6, MAVLinkCamV2) finds our camera (component 100) and sends one IMAGE_START_CAPTURE
per picture (`--cam-type 5`: AP_Camera_MAVLink, one DO_DIGICAM_CONTROL to every component it has
heard). Every frame is scored against the SITL's own truth:

- truth position and velocity: SIM_STATE (the physics model, not the EKF) at 50 Hz on this script's
  link, stamped on arrival (host monotonic clock), interpolated at the true mid-exposure (the simulated
  device's event log);
- the autopilot clock: this script's own TIMESYNC exchange with the SITL (20 Hz, on a port at 2 Mbaud)
  brackets the SITL's boot time at the true mid-exposure by causality (`clock_reference`); the
  recorder's figure is the boot time its geotagger put the frame at (recomputed from the log,
  icgt.sim.evaluate.replayed_autopilot_times). The SITL's clock does not run evenly with the host's
  under load, so the bracket's half-width is printed with it;
- every commanded exposure once: the pictures in the SITL's dataflash log (CAM messages), its
  CAMERA_FEEDBACK, the camera's CAMERA_IMAGE_CAPTURED routed to us, the true exposures and the log's
  frames must all be the same count.

Goals (printed next to each figure): timing part of the geotag error p95 <= 2 cm; every commanded
exposure once; autopilot clock error p95 <= 1 ms with ArduPilot's TIMESYNC. Exits 2 with a message when
no binary is given; not part of `make test`. PX4 (--px4): not run by this script yet (docs/sitl.md).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
from pymavlink import DFReader, mavutil
from pymavlink.dialects.v20 import ardupilotmega as mav

from icgt.geodesy import LocalFrame
from icgt.sim.evaluate import read_frames, read_truth, replayed_autopilot_times
from icgt.sim.recorder_setup import recorder_config_text
from icgt.sim.scenario import load_scenario
from icgt.sim.session import SimSession

REPO = Path(__file__).resolve().parents[1]
SCENARIO = REPO / "tests/e2e/ardupilot_commanded.toml"  # the device's clocks and camera body
GOAL_TIMING_CM = 2.0
GOAL_CLOCK_MS = 1.0
TAKEOFF_M = 5.0
LINE_M = 12.0
TRIGG_DIST_M = 1.5
INTERVAL_S = 1.0
SCAN_TOP_M = 14.0
PARAMS = {  # on top of Tools/autotest/default_params/copter.parm
    "CAM1_TYPE": 6,  # MAVLinkCamV2: IMAGE_START_CAPTURE to component 100
    "WPNAV_SPEED": 150,  # cm/s along the line
    "WPNAV_SPEED_UP": 80,  # cm/s up the scan line
    "SIM_SPEEDUP": 1,
    # ArduPilot answers TIMESYNC with the request's receive time less its transfer time at the port's baud
    # rate (AP_HAL_SITL UARTDriver::receive_time_constraint_us), also on the SITL's TCP ports, where the
    # baud rate is only nominal: at the default 115200 that puts tc1 ~2.5 ms before the SITL read it. A
    # companion UART runs at 921600 (SERIAL1, the recorder's); this script's reference link at 2 Mbaud
    # (~0.15 ms for a TIMESYNC).
    "SERIAL0_BAUD": 2000,
    "SERIAL1_BAUD": 921,
}


def fail(msg: str) -> int:
    print(f"sitl_flight: {msg}", file=sys.stderr)
    return 2


def pct(values: list[float], unit: str, goal: float | None = None) -> str:
    if not values:
        return "n/a"
    a = np.abs(np.asarray(values, dtype=float))
    s = f"p50 {np.percentile(a, 50):7.3f}  p95 {np.percentile(a, 95):7.3f}  max {a.max():7.3f} {unit} (n={a.size})"
    if goal is not None:
        s += f"   goal p95 <= {goal:g} {unit}: {'met' if np.percentile(a, 95) <= goal else 'NOT met'}"
    return s


class Gcs:
    """This script's link to the SITL (SERIAL0): SIM_STATE truth, TIMESYNC reference, camera messages."""

    def __init__(self, url: str) -> None:
        self.conn: Any = mavutil.mavlink_connection(url, source_system=255, source_component=190, autoreconnect=False)
        self.lock = threading.Lock()
        self.stop = threading.Event()
        self.sim: list[tuple[int, float, float, float, float, float, float]] = []  # host ns, lat, lon, alt, vn ve vd
        self.sync: list[tuple[int, int, int]] = []  # host mid ns, SITL boot ns, round trip ns
        self.msgs: dict[str, list[Any]] = {}
        self.texts: list[str] = []
        self.latest: dict[str, Any] = {}
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._ticker = threading.Thread(target=self._tick, daemon=True)

    def start(self) -> None:
        self._reader.start()
        self._ticker.start()

    def send(self, msg: Any) -> None:
        with self.lock:
            self.conn.mav.send(msg)

    def command(self, command: int, *params: float) -> None:
        p = [*params, 0, 0, 0, 0, 0, 0, 0][:7]
        self.send(self.conn.mav.command_long_encode(1, 1, command, 0, *p))

    def interval(self, msg_id: int, hz: float) -> None:
        self.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, 1e6 / hz)

    def _tick(self) -> None:
        while not self.stop.wait(0.05):  # 20 Hz
            with contextlib.suppress(OSError):
                self.send(self.conn.mav.timesync_encode(0, time.monotonic_ns()))

    def _read(self) -> None:
        while not self.stop.is_set():
            try:
                m = self.conn.recv_match(blocking=True, timeout=0.5)
            except (OSError, ConnectionError):
                return
            now = time.monotonic_ns()
            if m is None:
                continue
            t = m.get_type()
            if t == "SIM_STATE":
                self.sim.append((now, m.lat_int * 1e-7, m.lon_int * 1e-7, m.alt, m.vn, m.ve, m.vd))
            elif t == "TIMESYNC" and m.tc1 != 0 and m.get_srcSystem() == 1:
                self.sync.append(((m.ts1 + now) // 2, int(m.tc1), now - int(m.ts1)))
            elif t == "STATUSTEXT":
                self.texts.append(f"{(now / 1e9):.1f} {m.text}")
            if (m.get_srcSystem(), m.get_srcComponent()) == (1, 1):  # the autopilot's own, not the camera's
                self.latest[t] = m
            if t in ("CAMERA_FEEDBACK", "CAMERA_IMAGE_CAPTURED", "COMMAND_ACK", "MISSION_REQUEST", "MISSION_ACK",
                     "MISSION_REQUEST_INT", "MISSION_ITEM_REACHED", "GIMBAL_DEVICE_ATTITUDE_STATUS"):  # fmt: skip
                self.msgs.setdefault(t, []).append((now, m))

    def wait(self, what: str, pred: Any, timeout_s: float) -> None:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if pred():
                return
            time.sleep(0.1)
        raise TimeoutError(f"timed out after {timeout_s:g} s waiting for {what}; last texts: {self.texts[-5:]}")

    def close(self) -> None:
        self.stop.set()
        self._ticker.join(2)
        with contextlib.suppress(OSError):
            self.conn.close()
        self._reader.join(2)


class NoTimesyncRelay:
    """--no-timesync: the recorder's link through a TCP relay that drops every TIMESYNC both ways, so that
    the recorder sees an autopilot that never answers one (and sends none). Every other frame is passed
    on byte for byte (pymavlink's parser finds the frames). Adds a Python hop (~0.1 ms) each way."""

    def __init__(self, upstream_port: int) -> None:
        self.server = socket.create_server(("127.0.0.1", 0))
        self.port = int(self.server.getsockname()[1])
        self._upstream_port = upstream_port
        self.dropped = 0
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        self.server.settimeout(60)
        try:
            down, _ = self.server.accept()
        except OSError:
            return
        up = socket.create_connection(("127.0.0.1", self._upstream_port))
        for a, b in ((up, down), (down, up)):
            t = threading.Thread(target=self._pump, args=(a, b), daemon=True)
            t.start()
            self._threads.append(t)

    def _pump(self, src: socket.socket, dst: socket.socket) -> None:
        parser: Any = mav.MAVLink(None)
        parser.robust_parsing = True
        while not self._stop.is_set():
            try:
                data = src.recv(65536)
            except OSError:
                return
            if not data:
                return
            out = bytearray()
            for m in parser.parse_buffer(data) or []:
                if m.get_type() == "TIMESYNC":
                    self.dropped += 1
                elif m.get_type() != "BAD_DATA":
                    out += m.get_msgbuf()
            with contextlib.suppress(OSError):
                dst.sendall(bytes(out))

    def close(self) -> None:
        self._stop.set()
        self.server.close()


def upload_mission(gcs: Gcs, home: tuple[float, float, float]) -> int:
    lat0, lon0, _ = home
    north = LINE_M / 111_320.0
    rel = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    items = [  # (command, frame, params 1-4, lat, lon, alt)
        (mav.MAV_CMD_NAV_WAYPOINT, mav.MAV_FRAME_GLOBAL, (0, 0, 0, 0), lat0, lon0, 0.0),  # home, replaced
        (mav.MAV_CMD_NAV_TAKEOFF, rel, (0, 0, 0, 0), lat0, lon0, TAKEOFF_M),
        (mav.MAV_CMD_DO_SET_CAM_TRIGG_DIST, rel, (TRIGG_DIST_M, 0, 0, 0), 0, 0, 0),
        (mav.MAV_CMD_NAV_WAYPOINT, rel, (0, 0, 0, 0), lat0 + north, lon0, TAKEOFF_M),
        (mav.MAV_CMD_DO_SET_CAM_TRIGG_DIST, rel, (0, 0, 0, 0), 0, 0, 0),
        (mav.MAV_CMD_IMAGE_START_CAPTURE, rel, (0, INTERVAL_S, 0, 0), 0, 0, 0),  # forever, every INTERVAL_S
        (mav.MAV_CMD_NAV_WAYPOINT, rel, (0, 0, 0, 0), lat0 + north, lon0, SCAN_TOP_M),  # the vertical scan line
        (mav.MAV_CMD_IMAGE_STOP_CAPTURE, rel, (0, 0, 0, 0), 0, 0, 0),
        (mav.MAV_CMD_NAV_LAND, rel, (0, 0, 0, 0), lat0 + north, lon0, 0.0),
    ]
    gcs.msgs.pop("MISSION_REQUEST_INT", None)
    gcs.msgs.pop("MISSION_REQUEST", None)
    gcs.msgs.pop("MISSION_ACK", None)
    gcs.send(gcs.conn.mav.mission_count_encode(1, 1, len(items), 0))
    answered = 0
    end = time.monotonic() + 20
    while time.monotonic() < end:
        if gcs.msgs.get("MISSION_ACK"):
            ack = gcs.msgs["MISSION_ACK"][0][1]
            if ack.type != mav.MAV_MISSION_ACCEPTED:
                raise RuntimeError(f"mission refused: MISSION_ACK type {ack.type}")
            return len(items)
        reqs = sorted(gcs.msgs.get("MISSION_REQUEST_INT", []) + gcs.msgs.get("MISSION_REQUEST", []), key=lambda x: x[0])
        for _, r in reqs[answered:]:  # each request answered once, in order
            answered += 1
            cmd, frame, p, lat, lon, alt = items[r.seq]
            gcs.send(
                gcs.conn.mav.mission_item_int_encode(
                    1, 1, r.seq, frame, cmd, 0, 1, *p, round(lat * 1e7), round(lon * 1e7), alt, 0
                )
            )
        time.sleep(0.05)
    raise TimeoutError("mission upload: no MISSION_ACK")


def fly(gcs: Gcs, home: tuple[float, float, float]) -> None:
    gcs.interval(mav.MAVLINK_MSG_ID_SIM_STATE, 50.0)
    gcs.interval(mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, 5.0)
    gcs.interval(mav.MAVLINK_MSG_ID_HEARTBEAT, 1.0)
    gcs.wait("SIM_STATE", lambda: len(gcs.sim) > 10, 30)
    n_items = upload_mission(gcs, home)
    print(f"mission uploaded: {n_items} items")

    def armed() -> bool:
        hb = gcs.latest.get("HEARTBEAT")
        return hb is not None and bool(hb.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)

    end = time.monotonic() + 180
    while not armed():  # pre-arm checks pass once the EKF has its origin and GPS
        if time.monotonic() > end:
            raise TimeoutError(f"could not arm in 180 s; last texts: {gcs.texts[-5:]}")
        gcs.command(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4)  # GUIDED
        gcs.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        time.sleep(2.0)
    gcs.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, TAKEOFF_M)
    gcs.wait(
        "take-off",
        lambda: "GLOBAL_POSITION_INT" in gcs.latest and gcs.latest["GLOBAL_POSITION_INT"].relative_alt > 4500,
        60,
    )
    gcs.command(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 3)  # AUTO
    gcs.command(mav.MAV_CMD_MISSION_START, 0, 0)
    print("flying the mission")
    gcs.wait("the end of the mission (landed, disarmed)", lambda: not armed(), 300)


REF_WINDOW_NS = 1e9


def clock_reference(sync: list[tuple[int, int, int]]) -> Any:
    """host monotonic ns -> (SITL boot us, half-width of what it can be [us]), from this script's TIMESYNC.

    Causality only: the SITL read the request (tc1, less its ~0.15 ms transfer time at 2 Mbaud) after
    the host sent it (ts1) and before the reply came back (rx), so the offset tc1 - host lies in
    [tc1 - rx, tc1 - ts1] for every exchange. The SITL's clock does not run evenly with the host's
    (it falls behind under load and jumps: see `clock_irregularity`), so only exchanges within +-1 s
    count: the tightest consistent bracket (largest lower, smallest upper bound) if there is one, else
    the single exchange with the shortest round trip; the reference is its middle, its half-width the
    uncertainty. Written by hand: the bracket is the point (the recorder's estimator is under test).
    """
    a = np.asarray(sync, dtype=np.float64)
    mid, tc1, rtt = a[:, 0], a[:, 1], a[:, 2]
    lower = tc1 - (mid + rtt / 2)  # tc1 - rx
    upper = tc1 - (mid - rtt / 2)  # tc1 - ts1

    def at(host_ns: float) -> tuple[float, float]:
        near = np.flatnonzero(np.abs(mid - host_ns) < REF_WINDOW_NS)
        if near.size == 0:
            return math.nan, math.inf
        lo, hi = float(lower[near].max()), float(upper[near].min())
        if lo > hi:  # the clock moved within the window: the closest tight exchange alone
            k = near[np.argmin(rtt[near] + np.abs(mid[near] - host_ns) * 1e-3)]
            lo, hi = float(lower[k]), float(upper[k])
        return (host_ns + (lo + hi) / 2) / 1000.0, (hi - lo) / 2000.0

    return at


def clock_irregularity(sync: list[tuple[int, int, int]]) -> tuple[float, float]:
    """(mean rate of the SITL clock against the host's [ppm], p95 of its step between exchanges [ms])."""
    a = np.asarray(sync, dtype=np.float64)
    good = a[a[:, 2] < np.percentile(a[:, 2], 50)]
    off = good[:, 1] - good[:, 0]
    rate = float(np.polyfit(good[:, 0] * 1e-9, off * 1e-9, 1)[0]) * 1e6
    return rate, float(np.percentile(np.abs(np.diff(off)), 95)) / 1e6


def score(
    out: Path,
    gcs: Gcs,
    mcap: Path,
    truth_path: Path,
    sitl_dir: Path,
    home: tuple[float, float, float],
    timesync: bool,
    cam_type: int,
) -> int:
    frames = sorted(read_frames(mcap), key=lambda f: int(f["start_device_us"]))
    truth = sorted(read_truth(truth_path), key=lambda t: int(t["mid_host_monotonic_ns"]))
    sim = np.asarray(gcs.sim, dtype=np.float64)
    ref = clock_reference(gcs.sync)
    mapped = replayed_autopilot_times(mcap)
    local = LocalFrame(*home)
    by_start = {int(t["start_device_us"]): t for t in truth}
    pos_cm: list[float] = []
    timing_cm: list[float] = []
    clock_ms: list[float] = []
    host_ms: list[float] = []
    ref_ms: list[float] = []
    speeds: list[float] = []
    for fr in frames:
        t = by_start.get(int(fr["start_device_us"]))
        if t is None:
            continue
        h = float(t["mid_host_monotonic_ns"])
        lat, lon, alt, vn, ve, vd = (float(np.interp(h, sim[:, 0], sim[:, k])) for k in range(1, 7))
        speed = math.sqrt(vn * vn + ve * ve + vd * vd)
        speeds.append(speed)
        host_ms.append((int(fr["mid_host_ns"]) - h) / 1e6)
        got = mapped.get(int(fr["mid_host_ns"]))
        if got is not None:
            want_us, half_us = ref(h)
            ref_ms.append(half_us / 1000.0)
            err_ms = (got - want_us) / 1000.0
            clock_ms.append(err_ms)
            timing_cm.append(abs(err_ms) * 1e-3 * speed * 100.0)
        if fr.get("lat_deg") is not None:
            got_enu = local.geodetic_to_enu(fr["lat_deg"], fr["lon_deg"], fr["alt_msl_m"])
            d = np.subtract(got_enu, local.geodetic_to_enu(lat, lon, alt))
            pos_cm.append(float(np.linalg.norm(d)) * 100.0)
    cams = []
    for log in sorted((sitl_dir / "logs").glob("*.BIN")):
        df = DFReader.DFReader_binary(str(log))
        while (m := df.recv_match(type="CAM")) is not None:
            cams.append(int(m.Img))
    feedback = [int(m.img_idx) for _, m in gcs.msgs.get("CAMERA_FEEDBACK", [])]
    captured = sorted({int(m.image_index) for _, m in gcs.msgs.get("CAMERA_IMAGE_CAPTURED", [])})
    counts = {
        "dataflash CAM (ArduPilot's own log)": len(cams),
        "CAMERA_FEEDBACK to the ground station": len(feedback),
        "CAMERA_IMAGE_CAPTURED (distinct indices)": len(captured),
        "true exposures (device)": len(truth),
        "frames in the log": len(frames),
        "frames with one true exposure": len({int(f["start_device_us"]) for f in frames} & set(by_start)),
    }
    once = len(set(counts.values())) == 1 and len(truth) > 0
    backend = "MAVLinkCamV2" if cam_type == 6 else "MAVLink, DO_DIGICAM_CONTROL"
    how = "with TIMESYNC" if timesync else "WITHOUT TIMESYNC (relay drops it both ways)"
    print(f"\nArduCopter SITL flight, icgt record on SERIAL1 {how},")
    print(f"camera commanded by CAM1_TYPE = {cam_type} ({backend})")
    for k, v in counts.items():
        print(f"  {k:44s} {v}")
    print(f"  every commanded exposure recorded once:      {'yes' if once else 'NO'} (goal: yes)")
    rtt = np.asarray([s[2] for s in gcs.sync], dtype=float) / 1e6
    print(f"  reference TIMESYNC round trip [ms]           p50 {np.median(rtt):.3f} (n={rtt.size})")
    print(f"  reference clock uncertainty (half bracket)   {pct(ref_ms, 'ms')}")
    outside = [max(0.0, abs(e) - r) for e, r in zip(clock_ms, ref_ms, strict=True)]
    print(f"  autopilot clock error beyond that [ms]       {pct(outside, 'ms')}")
    rate_ppm, step_ms = clock_irregularity(gcs.sync)
    print(f"  SITL clock vs host: rate {rate_ppm:+.0f} ppm, steps between exchanges p95 {step_ms:.2f} ms")
    print(f"  true speed at the exposures [m/s]            max {max(speeds, default=0):.2f}")
    print(f"  mid-exposure host time error [ms]            {pct(host_ms, 'ms')}")
    print(f"  autopilot clock at mid-exposure [ms]         {pct(clock_ms, 'ms', GOAL_CLOCK_MS if timesync else None)}")
    print(f"  timing part of the geotag error [cm]         {pct(timing_cm, 'cm', GOAL_TIMING_CM)}")
    print(f"  geotag error vs SIM_STATE (incl. EKF) [cm]   {pct(pos_cm, 'cm')}")
    result = {
        "timesync": timesync,
        "cam1_type": cam_type,
        "counts": counts,
        "every_exposure_once": once,
        "clock_ms": clock_ms,
        "timing_cm": timing_cm,
        "geotag_cm": pos_cm,
        "host_ms": host_ms,
        "reference_half_bracket_ms": ref_ms,
        "sitl_clock_rate_ppm_step_p95_ms": clock_irregularity(gcs.sync),
        "reference_timesync": gcs.sync,
        "dataflash_cam_img": cams,
        "camera_feedback_img_idx": feedback,
        "image_captured": captured,
        "gimbal_device_attitude_status": len(gcs.msgs.get("GIMBAL_DEVICE_ATTITUDE_STATUS", [])),
    }
    (out / "result.json").write_text(json.dumps(result, indent=1) + "\n", encoding="utf-8")
    ok = bool(once and clock_ms and np.percentile(timing_cm, 95) <= GOAL_TIMING_CM)
    if timesync:  # without it the clock figure is stated, not held to the goal
        ok = ok and np.percentile(np.abs(clock_ms), 95) <= GOAL_CLOCK_MS
    return 0 if ok else 1


def set_params(
    binary: Path, defaults: Path, sitl_dir: Path, home: tuple[float, float, float], params: dict[str, float]
) -> None:
    """A first boot that stores PARAMS in the SITL's eeprom.bin (CAM1_TYPE given by --defaults reads 0 here)."""
    with (sitl_dir / "sitl_params.log").open("wb") as log:
        proc = subprocess.Popen(
            [str(binary), "--model", "+", "--speedup", "1", "-I0", "--wipe", "--defaults", str(defaults),
             "--home", f"{home[0]},{home[1]},{home[2]},0"],
            cwd=sitl_dir, stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
        )  # fmt: skip
    try:
        conn: Any = None
        for _ in range(50):
            try:
                conn = mavutil.mavlink_connection("tcp:127.0.0.1:5760", source_system=255, autoreconnect=False)
                break
            except OSError:
                time.sleep(0.2)
        if conn is None:
            raise RuntimeError(f"the SITL did not open TCP 5760; see {sitl_dir / 'sitl_params.log'}")
        conn.wait_heartbeat(timeout=30)
        for name, value in params.items():
            for _ in range(10):
                conn.mav.param_set_send(1, 1, name.encode(), float(value), mav.MAV_PARAM_TYPE_REAL32)
                m = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=1.0)
                if m is not None and m.param_id == name and abs(m.param_value - value) < 1e-6:
                    break
            else:
                raise RuntimeError(f"the SITL did not take {name} = {value}")
        time.sleep(2.0)  # the parameter store is written behind
        conn.close()
    finally:
        stop_process(proc, group=True)


def stop_process(proc: subprocess.Popen[bytes] | None, group: bool = False) -> None:
    if proc is None or proc.poll() is not None:
        return
    with contextlib.suppress(ProcessLookupError):
        if group:
            os.killpg(proc.pid, signal.SIGTERM)
        else:
            proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(timeout=20)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ardupilot", type=Path, help="ArduCopter SITL binary (build/sitl/bin/arducopter)")
    parser.add_argument("--px4", type=Path, help="PX4 SITL (px4 with SIH); not flown by this script yet")
    parser.add_argument("--defaults", type=Path, help="copter.parm (default: beside the binary's source tree)")
    parser.add_argument("--out", type=Path, default=Path("bench-out/sitl_flight"))
    parser.add_argument(
        "--cam-type",
        type=int,
        choices=(6, 5),
        default=6,
        help="CAM1_TYPE: 6 MAVLinkCamV2 (IMAGE_START_CAPTURE), 5 MAVLink (DO_DIGICAM_CONTROL to every component)",
    )
    parser.add_argument(
        "--no-timesync", action="store_true", help="drop TIMESYNC between the SITL and the recorder (a relay)"
    )
    args = parser.parse_args()
    if args.ardupilot is None and args.px4 is None:
        return fail("give --ardupilot PATH (an ArduCopter SITL binary; docs/sitl.md says how to build one)")
    if args.px4 is not None and args.ardupilot is None:
        return fail("--px4: flying PX4 SITL is not implemented here yet (docs/sitl.md); give --ardupilot PATH")
    binary = args.ardupilot.resolve()
    if not binary.is_file() or not os.access(binary, os.X_OK):
        return fail(f"{binary}: not an executable ArduCopter SITL binary")
    defaults = args.defaults or binary.parents[3] / "Tools/autotest/default_params/copter.parm"
    if not defaults.is_file():
        return fail(f"{defaults}: no copter.parm (give --defaults PATH)")
    out = args.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    sitl_dir = out / "sitl"
    sitl_dir.mkdir(exist_ok=True)
    for old in (sitl_dir / "logs").glob("*.BIN"):
        old.unlink()

    base = load_scenario(SCENARIO)
    cam = msgspec.structs.replace(base.camera, lever_arm_m=(0.0, 0.0, 0.0))
    ap = msgspec.structs.replace(base.autopilot, camera=msgspec.structs.replace(base.autopilot.camera, backend="none"))
    sc = msgspec.structs.replace(base, name="sitl_flight", duration_s=900.0, camera=cam, autopilot=ap)
    home = (sc.origin.lat_deg, sc.origin.lon_deg, sc.origin.alt_m)

    set_params(binary, defaults, sitl_dir, home, {**PARAMS, "CAM1_TYPE": args.cam_type})
    for old in (sitl_dir / "logs").glob("*.BIN"):
        old.unlink()
    sitl: subprocess.Popen[bytes] | None = None
    rec: subprocess.Popen[bytes] | None = None
    session = SimSession(sc, out / "sim", autopilot=False)
    gcs: Gcs | None = None
    relay: NoTimesyncRelay | None = None
    try:
        with (sitl_dir / "sitl.log").open("wb") as log:
            sitl = subprocess.Popen(
                [str(binary), "--model", "+", "--speedup", "1", "-I0", "--defaults", str(defaults),
                 "--home", f"{home[0]},{home[1]},{home[2]},0"],
                cwd=sitl_dir, stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
            )  # fmt: skip
        time.sleep(1.0)
        for _ in range(50):
            try:
                gcs = Gcs("tcp:127.0.0.1:5760")
                break
            except OSError:
                time.sleep(0.2)
        if gcs is None:
            return fail(f"the SITL did not open TCP 5760; see {sitl_dir / 'sitl.log'}")
        gcs.start()
        relay = NoTimesyncRelay(5762) if args.no_timesync else None
        mavlink_url = f"tcp:127.0.0.1:{relay.port}" if relay is not None else "tcp:127.0.0.1:5762"
        urls = session.start()
        rec_dir = out / "recording"
        config = out / "recorder.toml"
        config.write_text(recorder_config_text(sc, rec_dir, ground_stations=(255,)), encoding="utf-8")
        with (out / "recorder.log").open("w") as rlog:
            rec = subprocess.Popen(
                [sys.executable, "-m", "icgt.cli", "record", "--config", str(config), "--device", urls.device,
                 "--mavlink", mavlink_url, "--out", str(rec_dir), "--socket", str(out / "recorder.sock")],
                stdout=rlog, stderr=subprocess.STDOUT, env={**os.environ, "PYTHONUNBUFFERED": "1"},
            )  # fmt: skip
        fly(gcs, home)
        time.sleep(3.0)  # the last CAMERA_IMAGE_CAPTURED and frames
    finally:
        stop_process(rec)
        session.stop()
        if gcs is not None:
            gcs.close()
        stop_process(sitl, group=True)
        if relay is not None:
            relay.close()
            print(f"relay: {relay.dropped} TIMESYNC dropped")
    mcaps = sorted((out / "recording").glob("*.mcap"))
    if rec is None or rec.returncode != 0 or not mcaps:
        return fail(f"the recorder failed (exit {rec.returncode if rec else None}); see {out / 'recorder.log'}")
    return score(
        out, gcs, mcaps[-1], session.files.truth_exposures, sitl_dir, home, not args.no_timesync, args.cam_type
    )


if __name__ == "__main__":
    raise SystemExit(main())
