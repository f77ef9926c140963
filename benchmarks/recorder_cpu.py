#!/usr/bin/env python3
"""Benchmark: the recorder's CPU use, at nominal rates and under a MAVLink flood, next to a floor.

    .venv/bin/python benchmarks/recorder_cpu.py [--out bench-out/recorder_cpu] [--flood-hz 10000] [--baseline-rev REV]

With --baseline-rev the recorder of an earlier revision (its host/ package, exported with git archive and
put first on the recorder's PYTHONPATH) is flown too, each flight next to the same flight of this tree,
so that before and after are measured in one run, under the same load.

1. Nominal: the deck_pass scenario (5 fps, IMU 100 Hz, range 500 Hz, GLOBAL_POSITION_INT 50 Hz and the
   other telemetry) flown through the real links with `icgt record` as its own process; its CPU time is
   read from /proc over 10 s from 3 s after its log appeared (steady state: start-up and imports excluded).
2. Flood: the same flight while another process sends ``--flood-hz`` MAVLink messages per second from
   ten foreign systems to the recorder's UDP port (a busy shared network or a swarm on one radio). On a
   loaded machine the recorder may not get the CPU it needs, handle fewer datagrams and the kernel drop
   the rest: then the measured % is low for that reason. So the cost per foreign frame it logged is
   printed too ((CPU of the flood flight - CPU of the nominal flight) / frames logged) and the rate it
   implies (nominal % + cost x flood rate).
3. Floor: the same raw inputs (every MAVLink frame and every device message of the nominal flight's
   log, re-framed) pushed through what any recorder must do at least: pymavlink's parser for MAVLink,
   the protocol decoder for the device bytes, and the official mcap Writer storing each message raw.
   Measured in one process as CPU seconds per second of flight (no threads, no I/O waits: a floor).

4. Recompute: the nominal flight's log recomputed offline with its own settings (the same synchroniser);
   CPU time per second of flight, scaled to one hour.

Targets (issue 14): nominal <= 5 % of one core, flood < 30 %.
"""

from __future__ import annotations

import argparse
import base64
import io
import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

from icgt.demo import fly
from icgt.errors import IcgtError
from icgt.ingest.reader import read
from icgt.sim.scenario import load_scenario

CLK_TCK = os.sysconf("SC_CLK_TCK")


def cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK


def find_recorder(out: Path, timeout_s: float = 60.0) -> tuple[int, int]:
    """(pid, MAVLink UDP port) of the `icgt record` process writing under `out`."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for d in Path("/proc").iterdir():
            if not d.name.isdigit():
                continue
            try:
                argv = (d / "cmdline").read_bytes().split(b"\0")
            except OSError:
                continue
            if b"record" in argv and str(out.resolve()).encode() in b" ".join(argv):
                url = argv[argv.index(b"--mavlink") + 1].decode()
                return int(d.name), int(url.rsplit(":", 1)[1])
        time.sleep(0.2)
    raise RuntimeError(f"no recorder process for {out}")


class Sampler(threading.Thread):
    """Reads the recorder's CPU time over a window that starts `t0_s` after its log appeared (its links are
    then open: on a loaded machine its imports alone take seconds) and lasts `t1_s - t0_s`. A flood starts
    when the log appears."""

    def __init__(self, out: Path, t0_s: float, t1_s: float, flood_hz: float = 0.0) -> None:
        super().__init__(daemon=True)
        self.out, self.t0, self.t1, self.flood_hz = out, t0_s, t1_s, flood_hz
        self.result = float("nan")
        self.flood_sent = 0

    def run(self) -> None:
        pid, port = find_recorder(self.out)
        deadline = time.monotonic() + 60.0
        while not list((self.out / "recording").glob("*.mcap")) and time.monotonic() < deadline:
            time.sleep(0.05)
        start = time.monotonic()
        flooder = None
        if self.flood_hz > 0:
            flooder = subprocess.Popen(
                [sys.executable, __file__, "--flood-worker", str(port), str(self.flood_hz), str(self.t1 + 2)],
                stdout=subprocess.PIPE,
                text=True,
            )
        try:
            time.sleep(max(0.0, self.t0 - (time.monotonic() - start)))
            c0, w0 = cpu_s(pid), time.monotonic()
            time.sleep(max(0.0, self.t1 - (time.monotonic() - start)))
            c1, w1 = cpu_s(pid), time.monotonic()
            self.result = 100.0 * (c1 - c0) / (w1 - w0)
        except FileNotFoundError:  # the recorder ended before the window did: no number
            pass
        if flooder is not None:
            out, _ = flooder.communicate(timeout=60)
            self.flood_sent = int(out.strip() or 0)


def flood_frames() -> list[bytes]:
    """The flood: MAVLink 2 telemetry of ten foreign systems, one frame per datagram."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink2

    frames: list[bytes] = []
    for sysid in range(42, 52):
        mav = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=1)
        for k in range(20):
            msgs = [
                mav.attitude_encode(k * 20, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0),
                mav.global_position_int_encode(k * 20, 473_977_419, 85_455_938, 488_000, 10_000, 0, 0, 0, 0),
                mav.gps_raw_int_encode(k * 20_000, 3, 473_977_419, 85_455_938, 488_000, 80, 120, 0, 0, 12),
                mav.param_value_encode(b"PARAM_%d" % k, float(k), 9, 900, k),
            ]
            frames += [bytes(m.pack(mav)) for m in msgs]
    return frames


def flood_worker(port: int, hz: float, duration_s: float) -> None:
    """Send `hz` MAVLink 2 telemetry messages per second (ten foreign systems) to 127.0.0.1:port."""
    frames = flood_frames()
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sent = 0
    start = time.monotonic()
    period = 0.005
    per_tick = max(1, round(hz * period))
    i = 0
    while time.monotonic() - start < duration_s:
        for _ in range(per_tick):
            sock.sendto(frames[i % len(frames)], ("127.0.0.1", port))
            i += 1
        sent += per_tick
        time.sleep(max(0.0, start + sent / hz - time.monotonic()))
    print(sent)


def _flight_inputs(mcap: Path) -> tuple[list[tuple[int, str, Any]], float]:
    """The flight's raw inputs in log order: (host receive ns, kind, raw MAVLink frame or device message)."""
    from icgt.ingest.recompute import device_message, iter_inputs
    from icgt.recording import layout

    out: list[tuple[int, str, Any]] = []
    for m in iter_inputs(read(mcap)):
        if m.topic.startswith(layout.MAVLINK_PREFIX) and isinstance(m.data.get("raw"), str):
            out.append((int(m.data["host_rx_ns"]), "mavlink", base64.b64decode(m.data["raw"])))
        elif m.topic in layout.DEVICE_TOPIC_TYPES:
            msg = device_message(layout.DEVICE_TOPIC_TYPES[m.topic], m.data)
            out.append((int(m.data["host_rx_ns"]), "device", msg))
    times = [t for t, _, _ in out]
    return out, (max(times) - min(times)) / 1e9


def floor_cpu_percent(inputs: list[tuple[int, str, Any]], flight_s: float) -> float:
    """CPU % of one core for the inputs parsed and stored raw, as a minimal recorder would."""
    from mcap.writer import Writer
    from pymavlink.dialects.v20 import ardupilotmega as mavlink2

    from icgt.protocol import StreamDecoder, encode_frame

    framed = [(t, k, encode_frame(x, i) if k == "device" else x) for i, (t, k, x) in enumerate(inputs, start=1)]
    t0 = time.process_time()
    w = Writer(io.BytesIO())
    w.start()
    schema = w.register_schema("raw", "", b"")
    ch_m = w.register_channel("/mavlink", "raw", schema)
    ch_d = w.register_channel("/device", "raw", schema)
    parser = mavlink2.MAVLink(None)
    parser.robust_parsing = True
    dec = StreamDecoder()
    for t, kind, b in framed:
        if kind == "mavlink":
            for msg in parser.parse_buffer(b) or []:
                w.add_message(ch_m, t, bytes(msg.get_msgbuf()), t)
        else:
            for _ in dec.feed(b):
                w.add_message(ch_d, t, b, t)
    w.finish()
    return 100.0 * (time.process_time() - t0) / flight_s


def ours_offline_cpu_percent(inputs: list[tuple[int, str, Any]], flight_s: float, tmp: Path) -> float:
    """CPU % of one core for the same inputs through the recorder's worker (payloads, log, synchroniser,
    frames every 10 ms of flight time) and the MAVLink parser, without threads or links."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink2

    from icgt.mavlink.link import MavlinkMessage
    from icgt.protocol import StreamDecoder, encode_frame
    from icgt.recorder import Recorder
    from icgt.recorder.config import RecorderConfig
    from icgt.recorder.inbox import DEVICE as _DEVICE
    from icgt.recorder.inbox import MAVLINK as _MAVLINK
    from icgt.recorder.log_file import register_channels
    from icgt.recording import McapRecorder

    framed = [(t, k, encode_frame(x, i) if k == "device" else x) for i, (t, k, x) in enumerate(inputs, start=1)]
    t0 = time.process_time()
    rec = Recorder(RecorderConfig())
    rec.log_file.mcap = McapRecorder(tmp)
    register_channels(rec.log_file.mcap)  # the benchmark drives the worker's own steps (no device, no links)
    parser = mavlink2.MAVLink(None)
    parser.robust_parsing = True
    dec = StreamDecoder()
    next_poll = framed[0][0]
    for t, kind, b in framed:
        if kind == "mavlink":
            for msg in parser.parse_buffer(b) or []:
                rec.inbox.dispatch((_MAVLINK, MavlinkMessage(msg, t), t))
        else:
            for received in dec.feed(b):
                rec.inbox.dispatch((_DEVICE, received, t))
        if t >= next_poll:
            rec.worker.work_once(t)
            next_poll = t + 10_000_000
    rec.log_file.mcap.close()
    cpu = time.process_time() - t0
    tmp.unlink(missing_ok=True)
    return 100.0 * cpu / flight_s


def flood_offline_us(tmp: Path, n: int = 30_000) -> float:
    """CPU [us] per foreign datagram through the MAVLink link's receive path (header split, counting, hand-off)
    and the recorder's worker (raw payload, batched record, synchroniser), in one process: what the flood
    costs apart from the receive system call and the wake-ups, independent of the machine's load."""
    from icgt.mavlink.link import LinkConfig, MavlinkLink
    from icgt.recorder import Recorder
    from icgt.recorder.config import RecorderConfig
    from icgt.recorder.inbox import MAVLINK as _MAVLINK
    from icgt.recorder.log_file import register_channels
    from icgt.recording import McapRecorder

    frames = flood_frames()
    rec = Recorder(RecorderConfig())
    rec.log_file.mcap = McapRecorder(tmp)
    register_channels(rec.log_file.mcap)
    link = MavlinkLink(LinkConfig(url="udpin:127.0.0.1:0", decode_systems=rec.mavlink_input.expanded_systems))
    put = rec.inbox.items.append
    try:  # as the recorder subscribes: other systems' frames in batches (a revision without them: one each)
        link.subscribe(lambda r: put((_MAVLINK, r, r.rx_ns)), undecoded=lambda b: put((_MAVLINK, b, b.rx_ns)))
    except TypeError:
        link.subscribe(lambda r: put((_MAVLINK, r, r.rx_ns)))
    t = time.monotonic_ns()
    t0 = time.process_time()
    for i in range(n):
        link._feed(frames[i % len(frames)], t + i * 100_000)
        if i % 1000 == 999:  # the worker steps every 100 ms: 1000 datagrams at 10 k/s
            rec.worker.drain(limit=None)
    rec.worker.drain(limit=None)
    rec.log_file.mcap.close()
    cpu = time.process_time() - t0
    tmp.unlink(missing_ok=True)
    return cpu / n * 1e6


def _export_baseline(rev: str, into: Path) -> Path:
    """The host package of git revision `rev` of this repository, unpacked under `into`: its PYTHONPATH."""
    repo = Path(__file__).resolve().parent.parent
    into.mkdir(parents=True, exist_ok=True)
    archive = subprocess.run(["git", "-C", str(repo), "archive", rev, "host"], check=True, capture_output=True)
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive.stdout, check=True)
    # The venv's editable install of this tree is a meta path finder, ahead of PYTHONPATH: without this the
    # "baseline" would import this tree's icgt. site imports sitecustomize after the .pth files: drop it there.
    (into / "host" / "sitecustomize.py").write_text(
        "import sys\n\n"
        "_EDITABLE = ('ScikitBuildInplaceFinder', 'ScikitBuildRedirectingFinder')\n"
        "sys.meta_path[:] = [f for f in sys.meta_path if type(f).__name__ not in _EDITABLE]\n"
    )
    return into / "host"


def _flight_cpu(sc: Any, out: Path, flood_hz: float, pythonpath: Path | None) -> tuple[float, int, Any]:
    """(recorder CPU %, flood messages sent, flight) for one flight; `pythonpath`: the recorder's code."""
    saved = os.environ.get("PYTHONPATH")
    if pythonpath is not None:
        os.environ["PYTHONPATH"] = str(pythonpath)
    try:
        # The demo gives the recorder 15 s to appear; on a loaded machine its imports alone can take that
        # long when cold: import once first (page cache, .pyc files), after a pause for the last flight's
        # processes to end.
        time.sleep(5.0)
        subprocess.run([sys.executable, "-c", "import icgt.cli, icgt.recorder.recorder"], check=True)
        sampler = Sampler(out.resolve(), 3.0, 13.0, flood_hz)
        sampler.start()
        flight = fly(sc, out.resolve())
        sampler.join(timeout=60)
    finally:
        if saved is None:
            os.environ.pop("PYTHONPATH", None)
        else:
            os.environ["PYTHONPATH"] = saved
    return sampler.result, sampler.flood_sent, flight


def _kernel_drops(flight: Any) -> str:
    """The datagrams the kernel dropped before the recorder read them (a full receive buffer), as counted by
    the recorder's link; "?" for a revision that does not count them."""
    counters = [d for _, d in read(flight.mcap).messages("/icgt/counters")]
    drops = counters[-1].get("mavlink", {}).get("kernel_drops") if counters else None
    return "?" if drops is None else str(drops)


def _logged_foreign(flight: Any) -> int:
    counters = [d for _, d in read(flight.mcap).messages("/icgt/counters")]
    return int(counters[-1].get("mavlink", {}).get("undecoded_frames", 0)) if counters else 0


def _offline(
    mcap: Path, out: Path, pythonpath: Path | None, *, here: bool = False
) -> tuple[float, float, float, float]:
    """(floor %, the worker's %, flight s, us per flood datagram) offline; `pythonpath`: the worker's code.

    Each variant in a fresh process (`here`: this one): in the benchmark's own process, with the simulator's
    modules and the flights' objects on the heap, the same code measured 40 % slower (the collector)."""
    if here:
        inputs, flight_s = _flight_inputs(mcap)
        floor = floor_cpu_percent(inputs, flight_s)
        ours = ours_offline_cpu_percent(inputs, flight_s, out)
        return floor, ours, flight_s, flood_offline_us(out)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    if pythonpath is not None:
        env["PYTHONPATH"] = str(pythonpath)
    got = subprocess.run(
        [sys.executable, __file__, "--offline-worker", str(mcap), str(out)], env=env, check=True,
        capture_output=True, text=True,
    )  # fmt: skip
    floor, ours, flight_s, flood_us = (float(x) for x in got.stdout.split())
    return floor, ours, flight_s, flood_us


def main() -> int:
    if len(sys.argv) > 1 and sys.argv[1] == "--flood-worker":
        flood_worker(int(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4]))
        return 0
    if len(sys.argv) > 1 and sys.argv[1] == "--offline-worker":
        print(*_offline(Path(sys.argv[2]), Path(sys.argv[3]), None, here=True))
        return 0
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("bench-out/recorder_cpu"))
    parser.add_argument("--flood-hz", type=float, default=10_000.0)
    parser.add_argument("--scenario", default="deck_pass")
    parser.add_argument("--offline-only", type=Path, metavar="MCAP", help="only part 3, on an existing log")
    parser.add_argument(
        "--baseline-rev",
        metavar="REV",
        help="also fly the recorder of git revision REV (its host/ package), interleaved: before/after columns",
    )
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    variants: list[tuple[str, Path | None]] = [("this tree", None)]
    if args.baseline_rev:
        base = _export_baseline(args.baseline_rev, args.out.resolve() / "baseline-src")
        variants.insert(0, (args.baseline_rev[:12], base))
    head = "".join(f"{name:>14s}" for name, _ in variants)
    load = os.getloadavg()
    print(f"load average at start {load[0]:.1f} {load[1]:.1f} {load[2]:.1f} on {os.cpu_count()} CPUs")
    mcap = args.offline_only
    if args.offline_only is None:
        sc = load_scenario(args.scenario)
        rows: dict[str, list[str]] = {"nominal": [], "flood": [], "per_frame": [], "projected": []}
        whole: dict[tuple[str, int], tuple[float, int]] = {}  # (flight, variant) -> (CPU s of the process, logged)
        for name, flood_hz in (("nominal", 0.0), ("flood", args.flood_hz)):
            for k, (label, pythonpath) in enumerate(variants):
                for attempt in (1, 2):  # a flight whose recorder started too late on a loaded machine: once more
                    try:
                        cpu, sent, flight = _flight_cpu(sc, args.out / f"{name}-{k}", flood_hz, pythonpath)
                        break
                    except IcgtError as exc:
                        if attempt == 2:
                            raise
                        print(f"  {name}, {label}: flight failed ({exc}); again", flush=True)
                rows[name].append(f"{cpu:12.1f} %")
                logged = _logged_foreign(flight)
                whole[name, k] = (flight.recorder_cpu_s, logged)
                if flood_hz:
                    # A CPU-starved recorder (a loaded machine) handles fewer datagrams and the kernel drops the
                    # rest: its CPU % then says little. The cost per foreign frame it did log does.
                    base_cpu, _ = whole["nominal", k]
                    per_frame_us = (flight.recorder_cpu_s - base_cpu) / max(logged, 1) * 1e6
                    nominal_cpu = float(rows["nominal"][k].strip(" %"))
                    rows["per_frame"].append(f"{per_frame_us:11.1f} us")
                    rows["projected"].append(f"{nominal_cpu + flood_hz * per_frame_us / 1e4:12.1f} %")
                extra = f", {sent} sent, {logged} logged undecoded" if flood_hz else ""
                extra += f", {_kernel_drops(flight)} datagrams dropped by the kernel"
                print(f"  {name}, {label}: {cpu:.1f} % of one core{extra}", flush=True)
                if pythonpath is None and name == "nominal":
                    mcap = flight.mcap
        print(f"recorder CPU of one core, steady state, {sc.name} (5 fps, IMU 100 Hz, range 500 Hz, telemetry 50 Hz)")
        print(f"{'':34s}{head}")
        print(f"{'  nominal rates (target <= 5 %)':34s}{''.join(rows['nominal'])}")
        print(f"{f'  + {args.flood_hz:,.0f} foreign msg/s, measured':34s}{''.join(rows['flood'])}")
        print(f"{'    CPU per foreign frame logged':34s}{''.join(rows['per_frame'])}")
        print(f"{'    -> nominal + that x rate (< 30 %)':34s}{''.join(rows['projected'])}")
    assert mcap is not None
    offline = [_offline(mcap, args.out / f"offline-{k}.mcap", p) for k, (_, p) in enumerate(variants)]
    flight_s = offline[-1][2]
    print(f"  the same {flight_s:.0f} s of inputs in one process, no threads or links:")
    print(f"{'    floor: pymavlink parse + mcap raw write':50s}" + "".join(f"{o[0]:12.1f} %" for o in offline))
    print(f"{'    the recorder worker (log, sync, frames)':50s}" + "".join(f"{o[1]:12.1f} %" for o in offline))
    print(f"{'    flood: link + worker per foreign datagram':50s}" + "".join(f"{o[3]:11.1f} us" for o in offline))
    print(
        f"{f'      x {args.flood_hz:,.0f}/s = % of one core':50s}"
        + "".join(f"{o[3] * args.flood_hz / 1e4:12.1f} %" for o in offline)
    )
    from icgt.ingest.recompute import recompute

    t0 = time.process_time()
    result = recompute(mcap)
    cpu = time.process_time() - t0
    per_hour_s = cpu / flight_s * 3600.0
    print(
        f"  recompute (icgt.ingest.recompute, own settings): {cpu:.1f} s CPU for {flight_s:.0f} s of flight, "
        f"{len(result.frames)} frames -> {per_hour_s / 60:.1f} min per hour of flight at these rates"
    )
    load = os.getloadavg()
    print(f"load average at end {load[0]:.1f} {load[1]:.1f} {load[2]:.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
