"""kill -9 in the middle of a recording: the file reads in stream mode, recovers to a complete indexed file,
and at most ~1 s (the chunk interval, plus scheduling slack) of what was written is missing."""

from __future__ import annotations

import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from mcap.exceptions import EndOfFile
from recording_checks import read_complete, read_unfinished

from icgt.recording import recover

CHILD = Path(__file__).with_name("kill_writer.py")
LOSS_BOUND_NS = 1_200_000_000  # max_chunk_interval_s (1.0 s) + 0.2 s for a busy CI machine


@pytest.mark.parametrize("rate_hz", [200.0, 4.0])
def test_kill_9_loses_at_most_one_second(tmp_path: Path, rate_hz: float) -> None:
    path = tmp_path / "killed.mcap"
    delay_s = random.uniform(1.3, 2.5)
    proc = subprocess.Popen([sys.executable, str(CHILD), str(path), str(rate_hz)], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == "started"
        time.sleep(delay_s)
        kill_ns = time.time_ns()
        proc.send_signal(signal.SIGKILL)
        out, _ = proc.communicate(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == -signal.SIGKILL
    handed_over = [int(line) for line in out.split()]  # log times whose write() returned before the kill
    context = f"rate {rate_hz} Hz, killed {delay_s:.2f} s after start, {len(handed_over)} messages written"

    # (a) the official reader reads the unfinished file in stream mode, up to its last complete record
    streamed, stopped_by = read_unfinished(path)
    assert streamed, f"nothing on disk: {context}"

    # (b) recover() makes a complete, indexed file holding the same messages
    fixed = tmp_path / "recovered.mcap"
    report = recover(path, fixed)
    back = read_complete(fixed)
    assert sorted((m[0], m[1]) for m in back.messages) == sorted(streamed), context
    assert report.messages == len(streamed) and not report.source_was_complete
    assert back.metadata["device"] == {"serial": "KILLTEST"}
    if not isinstance(stopped_by, EndOfFile):  # the kill cut the last write: only that tail may be missing
        assert report.bytes_discarded > 0, f"{stopped_by!r} but recover found no damaged tail: {context}"

    # (c) at most ~1 s lost: everything written more than LOSS_BOUND before the kill is in the file
    saved = {m[1] for m in back.messages}
    missing_old = [t for t in handed_over if t < kill_ns - LOSS_BOUND_NS and t not in saved]
    assert not missing_old, f"{len(missing_old)} messages older than 1.2 s were lost: {context}"
    if rate_hz >= 100:
        newest = max(saved)
        assert kill_ns - newest <= LOSS_BOUND_NS, (
            f"newest saved message {(kill_ns - newest) / 1e9:.3f} s old: {context}"
        )
