"""The recorder's fast payload encoders give the bytes of the mappings they replace (what readers and the
recompute parse), for every device message type and for other systems' MAVLink frames left undecoded."""

from __future__ import annotations

import dataclasses
import json
import math
import random

import msgspec
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from icgt.mavlink.frames import split_datagram
from icgt.protocol import MESSAGE_TYPES
from icgt.recorder import topics


def _filled(cls: type, rng: random.Random) -> object:
    """An instance of a device message with every field set to a value of its type."""
    msg = cls()
    for f in dataclasses.fields(msg):
        v = getattr(msg, f.name)
        if isinstance(v, float):
            setattr(msg, f.name, rng.uniform(-1e3, 1e3))
        elif isinstance(v, int):
            setattr(msg, f.name, rng.randrange(0, 200))
        elif isinstance(v, str):
            setattr(msg, f.name, 'text "quoted" null \u00e9')
    return msg


@pytest.mark.parametrize("cls", sorted(MESSAGE_TYPES.values(), key=lambda c: c.ID), ids=lambda c: c.NAME)
def test_device_payload_json_is_the_mapping_encoded(cls):
    rng = random.Random(cls.ID)
    encode = msgspec.json.Encoder().encode
    for msg in (cls(), _filled(cls, rng)):
        fast = topics.device_payload_json(msg, 7, 1, 1_234_567_890_123)
        assert fast == encode(topics.device_payload(msg, 7, 1, 1_234_567_890_123))
        parsed = json.loads(fast)
        assert parsed["seq"] == 7 and parsed["frame_flags"] == 1 and parsed["host_rx_ns"] == 1_234_567_890_123


def test_a_non_finite_float_is_left_out_as_in_the_mapping():
    floats = [
        (cls, f.name)
        for cls in MESSAGE_TYPES.values()
        for f in dataclasses.fields(cls())
        if isinstance(getattr(cls(), f.name), float)
    ]
    assert floats, "no device message has a float field"
    for cls, name in floats:
        msg = cls()
        setattr(msg, name, math.nan)
        fast = topics.device_payload_json(msg, 1, 0, 5)
        assert name not in json.loads(fast)
        assert fast == msgspec.json.encode(topics.device_payload(msg, 1, 0, 5))


def test_an_undecoded_frame_gives_the_payload_of_its_decoded_message():
    mav = mavlink2.MAVLink(None, srcSystem=42, srcComponent=7)
    buf = bytes(mav.attitude_encode(1000, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0).pack(mav))
    split = split_datagram(buf, frozenset({1}))
    assert split is not None
    (frame,) = split[1]
    parser = mavlink2.MAVLink(None)
    (decoded,) = parser.parse_buffer(buf)
    assert topics.mavlink_raw_payload(frame, 99) == topics.mavlink_raw_payload(decoded, 99)
