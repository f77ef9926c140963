"""The `icgt` command: the composition root of the host tools."""

from __future__ import annotations

import argparse
import json
import logging
import math
import signal
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from icgt.errors import IcgtError
from icgt.protocol import PROTOCOL_VERSION, TABLE_HASH, StreamDecoder
from icgt.protocol.canonical import dumps, message_dict
from icgt.version import __version__

log = logging.getLogger("icgt")


def _until_signal(stop: Callable[[], None]) -> threading.Event:
    """Call `stop` on SIGINT/SIGTERM (once); returns an event set when that happens."""
    done = threading.Event()

    def handler(signum: int, _frame: Any) -> None:
        if not done.is_set():
            done.set()
            log.info("stopping (%s)", signal.Signals(signum).name)
            stop()

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)
    return done


def _port(option: str, value: int) -> int:
    """A UDP/TCP port given on the command line, refused (IcgtError naming the option) outside 0..65535
    (0: any free port, the one taken is printed)."""
    if not 0 <= value <= 65535:
        raise IcgtError(f"{option} {value}: a port is a number from 1 to 65535 (or 0: any free port)")
    return value


def _seconds(option: str, value: float) -> float:
    """A duration given on the command line, refused (IcgtError naming the option) unless finite and > 0."""
    if not math.isfinite(value) or value <= 0.0:
        raise IcgtError(f"{option} {value}: a duration is a finite number of seconds greater than 0")
    return value


def _cmd_version(_: argparse.Namespace) -> int:
    print(_version_text())
    return 0


def _cmd_decode(args: argparse.Namespace) -> int:
    """Print every message of a raw device byte stream (e.g. a capture of the serial port) as JSON lines."""
    decoder = StreamDecoder()
    path: Path = args.stream
    try:
        with path.open("rb") as f:
            while chunk := f.read(65536):
                for received in decoder.feed(chunk):
                    print(dumps(message_dict(received)))
    except OSError as exc:
        raise IcgtError(f"cannot read {path}: {exc.strerror}") from exc
    stats = decoder.stats
    print(
        f"{stats.frames_ok} messages, {stats.rejected} frames rejected, {stats.seq_missed} missed by sequence "
        f"number, {decoder.pending_bytes} bytes of an unfinished frame at the end",
        file=sys.stderr,
    )
    return 0


def _cmd_record(args: argparse.Namespace) -> int:
    from icgt.control import default_socket_path
    from icgt.recorder import Recorder, load_config

    if args.live is not None:
        _port("--live", args.live)
    config = load_config(args.config).with_overrides(device_url=args.device, mavlink_url=args.mavlink, out_dir=args.out)
    recorder = Recorder(
        config, control_socket=args.socket or default_socket_path(), live_port=args.live, live_host=args.live_host
    )
    path = recorder.start()
    print(f"recording to {path}; control socket {args.socket or default_socket_path()}", flush=True)
    _until_signal(recorder.stop)
    recorder.wait()
    recorder.stop()
    if recorder.failure is not None:
        raise recorder.failure
    print(f"{recorder.frames} frames recorded in {path}")
    return 0


def _control(args: argparse.Namespace, message: dict[str, Any]) -> dict[str, Any]:
    from icgt.control import default_socket_path, request

    return request(args.socket or default_socket_path(), message)


def _cmd_start(args: argparse.Namespace) -> int:
    _control(args, {"command": "start", "interval_s": args.interval, "count": args.count})
    print("capture started")
    return 0


def _cmd_stop(args: argparse.Namespace) -> int:
    _control(args, {"command": "stop"})
    print("capture stopped")
    return 0


def _cmd_status(args: argparse.Namespace) -> int:
    reply = _control(args, {"command": "status"})
    print(json.dumps(reply["status"], indent=2))
    return 0


def _cmd_recover(args: argparse.Namespace) -> int:
    from icgt.recording import recover

    src: Path = args.source
    dst: Path = args.output or src.with_name(src.stem + "-recovered.mcap")
    report = recover(src, dst)
    print(report.describe())
    # 1: damaged records or chunks in the middle were skipped (data may be lost); a cut-off tail is what a crash leaves
    if report.lossy:
        print(
            f"icgt recover: {src}: damage inside the file was skipped ({len(report.skipped)} byte ranges, "
            f"{report.chunks_damaged} chunks; offsets above): the messages there are lost",
            file=sys.stderr,
        )
    return 1 if report.lossy else 0


def _cmd_recover_device(args: argparse.Namespace) -> int:
    from icgt.recorder.recover_device import recover_device

    result = recover_device(args.device, flight_path=args.flight, out=args.out)
    print(result.describe())
    if result.exposures_lost:
        print(
            f"icgt recover-device: {result.exposures_lost} exposures (or frames of unknown kind) of the range asked "
            "were no longer in the device's history (overwritten): they are lost",
            file=sys.stderr,
        )
        return 1
    return 0


def _cmd_sim(args: argparse.Namespace) -> int:
    from icgt.sim.scenario import load_scenario
    from icgt.sim.session import SimSession

    mavlink_port = _port("--mavlink-port", args.mavlink_port)
    gcs_port = _port("--gcs-port", args.gcs_port)
    duration = None if args.duration is None else _seconds("--duration", args.duration)
    scenario = load_scenario(args.scenario)
    session = SimSession(scenario, args.out, mavlink_port=mavlink_port, gcs_port=gcs_port)
    urls = session.start()
    print(f"scenario {scenario.name}: {scenario.duration_s:.0f} s", flush=True)
    print(f"  icgt record --device {urls.device} --mavlink {urls.mavlink}", flush=True)
    print(f"  ground station: {urls.gcs} (the autopilot routes it to the camera, component 100)", flush=True)
    stop = threading.Event()
    _until_signal(stop.set)
    try:
        session.wait_until(duration or scenario.duration_s, stop)
    finally:
        session.stop()
    print(f"truth written to {args.out}")
    return 0


def _cmd_match(args: argparse.Namespace) -> int:
    from icgt.ingest.match import cmd_match

    return cmd_match(args)


def _cmd_export(args: argparse.Namespace) -> int:
    from icgt.export.cli import cmd_export

    return cmd_export(args)


def _cmd_map(args: argparse.Namespace) -> int:
    from icgt.mapping.cli import cmd_map

    return cmd_map(args)


def _cmd_tiles(args: argparse.Namespace) -> int:
    from icgt.mapping.cli import cmd_tiles

    return cmd_tiles(args)


def _cmd_demo(args: argparse.Namespace) -> int:
    from icgt.demo import run_demo

    summary = run_demo(args.scenario, args.out)
    return 0 if summary.get("ok") else 1


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="icgt", description="ICGT image capturing and geo-tagging: host tools")
    parser.add_argument("--version", action="version", version=_version_text())
    _add_logging_options(parser, top=True)
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("version", help="print the package and protocol versions").set_defaults(func=_cmd_version)

    decode = sub.add_parser("decode", help="decode a raw device byte stream to JSON lines")
    decode.add_argument("stream", type=Path, help="file holding bytes read from the device's serial port")
    decode.set_defaults(func=_cmd_decode)

    record = sub.add_parser("record", help="record a flight: device + autopilot -> geotagged MCAP")
    record.add_argument("--device", help="device URL: /dev/ttyACM0, socket://host:port, the simulator's path")
    record.add_argument("--mavlink", help="autopilot URL: udpin:0.0.0.0:14550, tcp:host:port, /dev/ttyAMA0,921600")
    record.add_argument("--out", type=Path, help="output directory")
    record.add_argument("--config", type=Path, help="recorder configuration (TOML)")
    record.add_argument("--socket", type=Path, help="control socket path (default: in $XDG_RUNTIME_DIR)")
    record.add_argument(
        "--live",
        nargs="?",
        const=8765,
        type=int,
        metavar="PORT",
        help="serve every channel to the Foxglove app over WebSocket while recording (default port 8765)",
    )
    record.add_argument(
        "--live-host", default="127.0.0.1", metavar="ADDRESS", help="address the live view binds (default 127.0.0.1)"
    )
    record.set_defaults(func=_cmd_record)

    for name, func, text in (
        ("start", _cmd_start, "start capture on the running recorder"),
        ("stop", _cmd_stop, "stop capture on the running recorder"),
        ("status", _cmd_status, "show the running recorder's state"),
    ):
        p = sub.add_parser(name, help=text)
        p.add_argument("--socket", type=Path, help="control socket path")
        if name == "start":
            p.add_argument("--interval", type=float, help="seconds between shots (default: the config's)")
            p.add_argument("--count", type=int, default=0, help="shots (0: until stopped)")
        p.set_defaults(func=func)

    rec = sub.add_parser(
        "recover",
        help="turn an unfinished or damaged MCAP into a complete one (exit 1 if damaged records were skipped)",
    )
    rec.add_argument("source", type=Path)
    rec.add_argument("output", type=Path, nargs="?", help="default: SOURCE-recovered.mcap")
    rec.set_defaults(func=_cmd_recover)

    rdev = sub.add_parser(
        "recover-device",
        help="fetch what a device plugged in again still holds of a flight whose recording ended mid-outage",
    )
    rdev.add_argument("--device", default="/dev/ttyACM0", help="device URL (default /dev/ttyACM0)")
    rdev.add_argument("--flight", type=Path, help="the flight's log: checked against the device; the frames it lacks")
    rdev.add_argument("--out", type=Path, help="output .mcap file or folder (default: next to --flight, or here)")
    rdev.set_defaults(func=_cmd_recover_device)

    sim = sub.add_parser("sim", help="run a simulated device, autopilot and camera for a scenario")
    sim.add_argument("scenario", help="scenario name (pier_scan, deck_pass, hover) or TOML file")
    sim.add_argument("--out", type=Path, default=Path("sim-out"), help="truth and camera card directory")
    sim.add_argument("--mavlink-port", type=int, default=14550)
    sim.add_argument("--gcs-port", type=int, default=14551)
    sim.add_argument("--duration", type=float, help="seconds (default: the scenario's)")
    sim.set_defaults(func=_cmd_sim)

    match = sub.add_parser("match", help="pair the camera card's JPEGs with the recorded exposures")
    match.add_argument("log", type=Path, help="the recording (.mcap)")
    match.add_argument("--images", type=Path, required=True, help="folder of the camera card's JPEGs (only read)")
    match.add_argument("--json", type=Path, help="write the pairing, unmatched and ambiguous items as JSON")
    match.add_argument("--camera-id", type=int, help="only this camera port's frames")
    match.add_argument("--tolerance", type=float, help="EXIF time tolerance [s] (default 0.02)")
    match.add_argument("--no-progress", action="store_true", help="no progress bars")
    match.set_defaults(func=_cmd_match)

    from icgt.export.cli import add_export_arguments

    export = sub.add_parser(
        "export", help="match the card's JPEGs to a log; write CSV, GeoJSON, geo.txt, OpenSfM, geotagged JPEGs"
    )
    add_export_arguments(export)
    export.set_defaults(func=_cmd_export)

    from icgt.trajectories.cli import add_regeotag_arguments, cmd_regeotag

    regeo = sub.add_parser("regeotag", help="re-geotag a log's frames from a TUM (SLAM) or RTKLIB .pos (PPK) file")
    add_regeotag_arguments(regeo)
    regeo.set_defaults(func=cmd_regeotag)

    from icgt.ingest.calibrate_board import add_calibrate_board_arguments, cmd_calibrate_board

    calib = sub.add_parser("calibrate-board", help="the board IMU's alignment and north from a calibration flight")
    add_calibrate_board_arguments(calib)
    calib.set_defaults(func=cmd_calibrate_board)

    from icgt.report import add_info_arguments, add_report_arguments, cmd_info, cmd_report

    report = sub.add_parser("report", help="the flight report: one self-contained HTML page")
    add_report_arguments(report)
    report.set_defaults(func=cmd_report)
    info = sub.add_parser("info", help="a recording's summary in the terminal")
    add_info_arguments(info)
    info.set_defaults(func=cmd_info)

    from icgt.mapping.args import add_map_arguments, add_tiles_arguments

    mapping = sub.add_parser("map", help="place detections on the structure, merge them, write GeoJSON and a mosaic")
    add_map_arguments(mapping)
    mapping.set_defaults(func=_cmd_map)
    tiles = sub.add_parser("tiles", help="cut the card's images into 512 px detector tiles placed on the face")
    add_tiles_arguments(tiles)
    tiles.set_defaults(func=_cmd_tiles)

    from icgt.catalog.cli import add_catalog_arguments

    catalog = sub.add_parser("catalog", help="the inspection catalogue: add flights (GeoParquet), query them (DuckDB)")
    add_catalog_arguments(catalog)
    from icgt.catalog.compare_out import add_compare_arguments

    comparing = sub.add_parser("compare", help="compare two inspections of a structure: new, grown, repaired defects")
    add_compare_arguments(comparing)
    from icgt.batch import add_batch_arguments

    batch = sub.add_parser("batch", help="export, map or catalog-add many flights on Dask distributed")
    add_batch_arguments(batch)

    demo = sub.add_parser("demo", help="the main job on simulated hardware, with a summary against truth")
    demo.add_argument("--scenario", default="pier_scan")
    demo.add_argument("--out", type=Path, default=Path("demo-out"))
    demo.set_defaults(func=_cmd_demo)
    for subparser in sub.choices.values():  # -v/-q/--log-level after the subcommand too
        _add_logging_options(subparser, top=False)
    return parser


_LOG_LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR")


def _add_logging_options(parser: argparse.ArgumentParser, *, top: bool) -> None:
    """-v/-q/--log-level; on a subcommand they default to nothing, so the top-level choice stands."""
    group = parser.add_argument_group("logging")
    default = "INFO" if top else argparse.SUPPRESS
    group.add_argument(
        "-v", "--verbose", dest="log_level", action="store_const", const="DEBUG", default=default, help="debug logging"
    )
    group.add_argument(
        "-q", "--quiet", dest="log_level", action="store_const", const="WARNING", default=default, help="warnings only"
    )
    group.add_argument(
        "--log-level", dest="log_level", type=str.upper, choices=_LOG_LEVELS, default=default, help="log level"
    )


def _version_text() -> str:
    return f"icgt {__version__}, protocol version {PROTOCOL_VERSION}, table hash 0x{TABLE_HASH:08X}"


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=getattr(logging, args.log_level),
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    try:
        code: int = args.func(args)
    except IcgtError as exc:
        print(f"icgt: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130
    return code


if __name__ == "__main__":
    sys.exit(main())
