"""split_datagram: frames of other systems left undecoded by their headers, everything odd left to pymavlink."""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from icgt.mavlink.frames import split_datagram


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
