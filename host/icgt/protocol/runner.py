"""Decode a protocol test vector with the Python codec and print its canonical JSON.

python -m icgt.protocol.runner VECTOR.bin
"""

from __future__ import annotations

import sys
from pathlib import Path

from icgt.protocol.canonical import decoding
from icgt.protocol.codec import StreamDecoder


def run(path: Path) -> str:
    decoder = StreamDecoder()
    received = decoder.feed(path.read_bytes())
    return decoding(received, decoder.stats, decoder.pending_bytes)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        print("usage: python -m icgt.protocol.runner VECTOR.bin", file=sys.stderr)
        return 2
    try:
        print(run(Path(args[0])))
    except OSError as exc:
        print(f"{args[0]}: {exc.strerror}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
