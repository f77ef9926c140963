"""RESEND, RESEND_LOST and retransmitted frames through both codecs (hypothesis).

Random requests, answers and retransmit flags are framed by the Python encoder; the Python decoder and
the C++ vector runner (the firmware's codec) must both give back exactly what went in, and neither may
move its sequence expectation for a retransmitted frame (SPEC.md §3)."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from icgt.protocol import StreamDecoder, encode_frame
from icgt.protocol.messages import Exposure, FrameFlags, HostReceived, Pps, Resend, ResendLost

u32 = st.integers(0, 2**32 - 1)
u16 = st.integers(0, 2**16 - 1)

messages = st.one_of(
    st.builds(Resend, first_seq=u32, count=u16),
    st.builds(
        ResendLost, first_seq=u32, count=u32, resent=u32, exposures=u32, pps=u32, samples=u32, other=u32, unknown=u32
    ),
    st.builds(HostReceived, next_seq=u32),
    st.builds(Exposure, image_index=u32, trigger_t_us=st.integers(0, 2**64 - 1)),
    st.builds(Pps, t_us=st.integers(0, 2**64 - 1), pps_count=u32),
)
frames = st.lists(st.tuples(messages, u32, st.booleans()), min_size=1, max_size=20)


def _expected_missed(items: list[tuple[object, int, bool]]) -> tuple[int, int, int]:
    expected = None
    gaps = missed = resets = 0
    for _, seq, retx in items:
        if retx:
            continue
        if expected is not None and seq != expected:
            d = (seq - expected) & 0xFFFFFFFF
            if d < 2**31:
                gaps += 1
                missed += d
            else:
                resets += 1
        expected = (seq + 1) & 0xFFFFFFFF
    return gaps, missed, resets


@settings(max_examples=200, deadline=None)
@given(frames)
def test_python_codec_round_trips_resend_traffic(items: list[tuple[object, int, bool]]) -> None:
    stream = b"".join(encode_frame(m, seq, FrameFlags.RETRANSMIT if r else 0) for m, seq, r in items)  # type: ignore[arg-type]
    dec = StreamDecoder()
    got = dec.feed(stream)
    assert [(g.message, g.seq, bool(g.flags & FrameFlags.RETRANSMIT)) for g in got] == items
    gaps, missed, resets = _expected_missed(items)
    assert (dec.stats.seq_gaps, dec.stats.seq_missed, dec.stats.seq_resets) == (gaps, missed, resets)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(items=frames)
@example(items=[(Pps(t_us=0, pps_count=0), s, False) for s in (0, 0x7FFFFFFF, 0xFFFFFFFE, 0x7FFFFFFD)])
def test_cpp_codec_decodes_resend_traffic_like_python(
    items: list[tuple[object, int, bool]], cpp_vector_runner: Path, tmp_path: Path
) -> None:
    stream = b"".join(encode_frame(m, seq, FrameFlags.RETRANSMIT if r else 0) for m, seq, r in items)  # type: ignore[arg-type]
    path = tmp_path / "stream.bin"
    path.write_bytes(stream)
    out = json.loads(subprocess.run([cpp_vector_runner, path], capture_output=True, text=True, check=True).stdout)
    assert [(m["type"], m["seq"], m["flags"] & 1) for m in out["messages"]] == [
        (msg.NAME, seq, int(r))  # type: ignore[attr-defined]
        for msg, seq, r in items
    ]
    for m, (msg, _, _) in zip(out["messages"], items, strict=True):
        for name, value in m["fields"].items():
            assert getattr(msg, name) == value, (msg, name)
    gaps, missed, resets = _expected_missed(items)
    stats = out["stats"]
    # The firmware's u32 counter saturates (SPEC.md §3); the host's Python int does not need to.
    assert (stats["seq_gaps"], stats["seq_missed"], stats["seq_resets"]) == (gaps, min(missed, 2**32 - 1), resets)
