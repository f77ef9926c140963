"""The `icgt` command: the composition root of the host tools."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from icgt import __version__
from icgt.errors import IcgtError
from icgt.protocol import PROTOCOL_VERSION, TABLE_HASH, StreamDecoder
from icgt.protocol.canonical import dumps, message_dict


def _cmd_version(_: argparse.Namespace) -> int:
    print(f"icgt {__version__}, protocol version {PROTOCOL_VERSION}, table hash 0x{TABLE_HASH:08X}")
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


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="icgt", description="ICGT image capturing and geo-tagging: host tools")
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("version", help="print the package and protocol versions").set_defaults(func=_cmd_version)
    decode = sub.add_parser("decode", help="decode a raw device byte stream to JSON lines")
    decode.add_argument("stream", type=Path, help="file holding bytes read from the device's serial port")
    decode.set_defaults(func=_cmd_decode)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
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
