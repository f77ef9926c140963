"""split_datagram / split_foreign: frames of other systems left undecoded by their headers, everything odd left to
pymavlink; UndecodedBatch: what the link hands on in bulk."""

from __future__ import annotations

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from icgt.mavlink.frames import UndecodedBatch, split_datagram, split_foreign


def _frame(sysid: int, *, v1: bool = False, signed: bool = False, kind: str = "attitude") -> bytes:
    mav = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=1)
    if signed:
        mav.signing.secret_key = bytes(range(32))
        mav.signing.link_id = 1
        mav.signing.sign_outgoing = True
    if kind == "attitude":
        msg = mav.attitude_encode(1000, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0)
    elif kind == "command":
        msg = mav.command_long_encode(1, 100, 2000, 0, 0, 0.2, 0, 0, 0, 0, 0)
    else:
        msg = mav.heartbeat_encode(6, 8, 0, 0, 4)
    return bytes(msg.pack(mav, force_mavlink1=v1))


def test_frames_of_other_systems_are_split_off_with_their_ids_and_bytes() -> None:
    ours, theirs_v1, theirs_signed = _frame(1), _frame(42, v1=True), _frame(43, signed=True)
    split = split_datagram(ours + theirs_v1 + theirs_signed, frozenset({1, 255}))
    assert split is not None
    keep, other = split
    assert keep == ours
    assert [(f.src_system, f.get_type(), f.get_msgbuf()) for f in other] == [
        (42, "ATTITUDE", theirs_v1),
        (43, "ATTITUDE", theirs_signed),
    ]
    # the bytes left undecoded are whole frames pymavlink reads back as the messages sent
    parser = mavlink2.MAVLink(None)
    parser.robust_parsing = True
    msgs = parser.parse_buffer(theirs_v1) or []
    assert [m.get_srcSystem() for m in msgs] == [42]


def test_commands_and_heartbeats_are_decoded_from_anyone() -> None:
    data = _frame(245, kind="command") + _frame(250, kind="heartbeat") + _frame(77)
    split = split_datagram(data, frozenset({1}))
    assert split is not None
    keep, other = split
    assert keep == data[: len(keep)] and len(keep) == len(data) - len(_frame(77))
    assert [f.src_system for f in other] == [77]


def test_anything_but_whole_frames_goes_to_pymavlink() -> None:
    f = _frame(42)
    assert split_datagram(f[:-1], frozenset({1})) is None  # cut short
    assert split_datagram(b"\x00garbage" + f, frozenset({1})) is None  # junk before
    assert split_datagram(f + b"\xfd\x09", frozenset({1})) is None  # a header cut off
    assert split_datagram(b"", frozenset({1})) == (b"", [])


# --------------------------------------------------------------------------- split_foreign, UndecodedBatch
def test_split_foreign_appends_each_foreign_frame_with_its_receive_time() -> None:
    ours, v1, signed, cmd = _frame(1), _frame(42, v1=True), _frame(43, signed=True), _frame(44, kind="command")
    out: list = []
    assert split_foreign(v1, 5, frozenset({1}), out) == b""  # one frame, foreign: kept whole, not copied
    assert out[0][0] is v1 and out[0][1:] == (42, 1, mavlink2.MAVLINK_MSG_ID_ATTITUDE, 5)
    assert split_foreign(ours, 6, frozenset({1}), out) == ours and len(out) == 1  # ours: all to decode
    assert split_foreign(cmd, 6, frozenset({1}), out) == cmd and len(out) == 1  # a command, from anyone
    keep = split_foreign(signed + ours + v1, 7, frozenset({1}), out)
    assert keep == ours
    assert [(f[0], f[1], f[4]) for f in out] == [(v1, 42, 5), (signed, 43, 7), (v1, 42, 7)]


def test_split_foreign_leaves_the_list_as_it_was_when_not_whole_frames() -> None:
    theirs = _frame(42)
    out: list = [("earlier",)]
    assert split_foreign(theirs + theirs[:-1], 1, frozenset({1}), out) is None  # the second one cut short
    assert split_foreign(theirs + b"\x00junk", 1, frozenset({1}), out) is None
    assert split_foreign(theirs[:7], 1, frozenset({1}), out) is None
    assert out == [("earlier",)]
    assert split_foreign(b"", 1, frozenset({1}), out) == b""


def test_a_batch_counts_its_frames_by_type_version_and_bytes() -> None:
    frames: list = []
    unknown = bytearray(_frame(45))
    unknown[7:10] = (60_000).to_bytes(3, "little")  # a message id the dialect does not know
    for k, f in enumerate([_frame(42), _frame(43, v1=True), _frame(42, kind="heartbeat"), bytes(unknown)]):
        split_foreign(f, 100 + k, frozenset({1}), frames)
    # the heartbeat is decoded whoever sends it: three frames left
    batch = UndecodedBatch(frames)
    assert len(batch) == 3 and batch.rx_ns == 100
    assert batch.type_counts() == {"ATTITUDE": 2, "UNKNOWN_60000": 1}
    assert batch.v1_frames() == 1
    assert batch.size_bytes() == len(_frame(42)) + len(_frame(43, v1=True)) + len(unknown)
    singles = batch.undecoded_frames()
    assert [(f.get_type(), f.src_system, rx) for f, rx in singles] == [
        ("ATTITUDE", 42, 100),
        ("ATTITUDE", 43, 101),
        ("UNKNOWN_60000", 45, 103),
    ]
    assert UndecodedBatch(frames[:1]).type_counts() == {"ATTITUDE": 1}
    with pytest.raises(ValueError, match="at least one frame"):
        UndecodedBatch([])
