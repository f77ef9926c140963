"""One picture per shot when PX4's camera trigger asks for it twice (icgt.mavlink.camera_commanded)."""

from __future__ import annotations

import math

from mavlink_peers import wait_until
from pymavlink.dialects.v20 import common
from test_mavlink_camera import ACCEPTED, Rig

from icgt.mavlink.camera_commanded import PairingConfig, ShotPairing

NAN = math.nan
ISC, DIGICAM = common.MAV_CMD_IMAGE_START_CAPTURE, common.MAV_CMD_DO_DIGICAM_CONTROL
PX4_ISC = (0.0, 0.0, 1.0, 7.0, NAN, NAN, NAN)
PX4_DIGICAM = (NAN, NAN, NAN, NAN, 1.0, NAN, NAN)
AP = (1, 1)
MS = 1_000_000


def shoot(p: ShotPairing, t_ms: float, command: int, params, sender=AP, confirmation: int = 0) -> bool:
    """True: a picture is taken for this command."""
    paired = p.match(round(t_ms * MS), *sender, command, confirmation, params)
    if paired is None:
        p.taken(round(t_ms * MS), *sender, command, params)
    return paired is None


def test_px4_pair_is_one_picture_and_pairing_is_one_to_one() -> None:
    p = ShotPairing()
    assert shoot(p, 0, ISC, PX4_ISC)
    assert not shoot(p, 1, DIGICAM, PX4_DIGICAM)
    assert shoot(p, 2, DIGICAM, PX4_DIGICAM), "a second DO_DIGICAM_CONTROL is a second picture"
    assert shoot(p, 500, ISC, (0, 0, 1, 8, NAN, NAN, NAN))
    assert not shoot(p, 500, DIGICAM, PX4_DIGICAM)
    assert p.paired == 2


def test_lost_image_start_capture_then_its_resend_pairs_with_the_digicam_shot() -> None:
    p = ShotPairing(PairingConfig(pair_window_s=0.2, resend_window_s=2.0))
    assert shoot(p, 0, DIGICAM, PX4_DIGICAM)  # the IMAGE_START_CAPTURE before it was lost
    assert not shoot(p, 500, ISC, PX4_ISC, confirmation=1)
    assert shoot(p, 2600, ISC, (0, 0, 1, 9, NAN, NAN, NAN), confirmation=1), "past the resend window"


def test_not_paired_across_senders_windows_identities_or_other_commands() -> None:
    p = ShotPairing(PairingConfig(pair_window_s=0.2))
    assert shoot(p, 0, ISC, PX4_ISC)
    assert shoot(p, 1, DIGICAM, PX4_DIGICAM, sender=(255, 190)), "another sender"
    assert shoot(p, 300, DIGICAM, PX4_DIGICAM), "after the window"
    assert shoot(p, 1000, ISC, PX4_ISC)
    assert shoot(p, 1001, DIGICAM, (0, 0, 0, 0, 1, 4, 0)), "a command identity: its own picture"
    assert p.match(1002 * MS, *AP, ISC, 0, (0, 1.0, 0, 0, 0, 0, 0)) is None, "interval capture: not a single shot"
    assert p.match(1003 * MS, *AP, DIGICAM, 0, (0, 0, 0, 0, 0, 0, 0)) is None, "no shoot"


def test_camera_takes_one_picture_for_px4s_two_commands_and_acks_both(tmp_path) -> None:
    rig = Rig(tmp_path)
    try:
        since = rig.command(ISC, *PX4_ISC, peer=rig.ap)
        rig.command(DIGICAM, *PX4_DIGICAM, target=(0, 100), peer=rig.ap)
        assert rig.ack(ISC, since, peer=rig.ap).result == ACCEPTED
        assert rig.ack(DIGICAM, since, peer=rig.ap).result == ACCEPTED
        assert wait_until(lambda: len(rig.records) == 2)
        assert rig.recorder.count("shoot") == 1
        assert "same shot as IMAGE_START_CAPTURE #7" in rig.records[1].reason
        # ArduPilot's MAVLink backend: DO_DIGICAM_CONTROL alone, every parameter but param5 zero, to (0, 0)
        since = rig.command(DIGICAM, 0, 0, 0, 0, 1, 0, 0, target=(0, 0), peer=rig.ap)
        assert rig.ack(DIGICAM, since, peer=rig.ap).result == ACCEPTED
        assert rig.recorder.count("shoot") == 2
    finally:
        rig.close()
