"""LinkScheduler without sockets: TIMESYNC and stream-rate requests over time and the core's presence hints."""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from icgt.mavlink.link_scheduler import LinkScheduler
from icgt.mavlink.link_types import LinkConfig, StreamRate

MS = 1_000_000
ATT = StreamRate(mavlink2.MAVLINK_MSG_ID_ATTITUDE, "ATTITUDE", 50.0)
GPS = StreamRate(mavlink2.MAVLINK_MSG_ID_GPS_RAW_INT, "GPS_RAW_INT", 10.0)
_MAV = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)


def _config(**overrides: object) -> LinkConfig:
    cfg: dict[str, object] = dict(
        url="udpin:127.0.0.1:0",
        stream_rates=(ATT, GPS),
        rate_ack_timeout_s=0.5,
        timesync_fast_hz=5.0,
        timesync_fast_count=3,
        timesync_slow_hz=1.0,
    )
    cfg.update(overrides)
    return LinkConfig(**cfg)  # type: ignore[arg-type]


def _ack(result: int = mavlink2.MAV_RESULT_ACCEPTED) -> object:
    return _MAV.command_ack_encode(mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, result, 0, 0, 1, 100)


def _run(s: LinkScheduler, start_ns: int, end_ns: int, step_ns: int = 10 * MS, *, answer: bool = True) -> list:
    """Step the scheduler; every rate command is ACCEPTED 5 ms later when `answer`. What it asked, in order."""
    sent = []
    for now in range(start_ns, end_ns, step_ns):
        due = s.due(now)
        if due.rate is not None:
            sent.append((now, due.rate))
            if answer:
                s.on_command_ack(_ack(), now + 5 * MS)
    return sent


def _timesyncs(s: LinkScheduler, start_ns: int, end_ns: int, step_ns: int = 10 * MS) -> list[int]:
    return [now for now in range(start_ns, end_ns, step_ns) if s.due(now).timesync]


def test_nothing_is_asked_of_an_autopilot_the_core_has_not_named() -> None:
    s = LinkScheduler(_config())
    assert _run(s, 0, 2000 * MS) == []
    assert s.autopilot is None and s.rate_results() == []


def test_rates_are_asked_one_at_a_time_when_the_core_says_the_autopilot_appeared() -> None:
    s = LinkScheduler(_config())
    s.autopilot_appeared(1, 1, 0)
    sent = _run(s, 0, 1000 * MS)
    assert [c.rate for _, c in sent] == [ATT, GPS]
    assert all(c.target == (1, 1) and c.confirmation == 0 for _, c in sent)
    assert sent[1][0] > sent[0][0]  # the second only after the first's ACK
    assert {r.message_id for r in s.rate_results()} == {ATT.message_id, GPS.message_id}
    assert all(r.accepted for r in s.rate_results())


def test_rates_are_asked_again_after_the_core_says_back_or_rebooted_and_not_while_lost() -> None:
    s = LinkScheduler(_config())
    s.autopilot_appeared(1, 1, 0)
    assert len(_run(s, 0, 1000 * MS)) == 2
    s.autopilot_lost()
    assert _run(s, 1000 * MS, 5000 * MS) == []  # gone: nothing asked
    s.autopilot_appeared(1, 1, 5000 * MS)  # back
    assert [c.rate for _, c in _run(s, 5000 * MS, 6000 * MS)] == [ATT, GPS]
    s.autopilot_appeared(1, 1, 6000 * MS)  # rebooted (no loss in between: a short silence)
    assert [c.rate for _, c in _run(s, 6000 * MS, 7000 * MS)] == [ATT, GPS]


def test_a_loss_drops_the_pending_requests() -> None:
    s = LinkScheduler(_config())
    s.autopilot_appeared(1, 1, 0)
    assert len(_run(s, 0, 20 * MS, answer=False)) == 1  # ATTITUDE sent, not answered yet
    s.autopilot_lost()
    s.on_command_ack(_ack(), 30 * MS)  # nothing in flight: ignored
    assert s.rate_results() == []


def test_unanswered_requests_are_retried_with_their_confirmation_then_given_up() -> None:
    s = LinkScheduler(_config(rate_max_attempts=3, stream_rates=(ATT,)))
    s.autopilot_appeared(1, 1, 0)
    sent = _run(s, 0, 3000 * MS, answer=False)
    assert [c.confirmation for _, c in sent] == [0, 1, 2]
    assert [r.result for r in s.rate_results()] == [None]
    assert s.rate_results()[0].attempts == 3


def test_an_ack_for_another_component_is_not_ours() -> None:
    s = LinkScheduler(_config(stream_rates=(ATT,)))
    s.autopilot_appeared(1, 1, 0)
    assert len(_run(s, 0, 10 * MS, answer=False)) == 1
    other = _MAV.command_ack_encode(mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, 0, 0, 0, 255, 190)
    s.on_command_ack(other, 12 * MS)
    s.due(20 * MS)
    assert s.rate_results() == []


def test_timesync_is_fast_after_each_appearance_and_slow_otherwise() -> None:
    s = LinkScheduler(_config())
    slow = _timesyncs(s, 0, 3000 * MS)
    assert slow == [0, 1000 * MS, 2000 * MS]  # before the autopilot is there: 1 Hz
    s.autopilot_appeared(1, 1, 3000 * MS)
    fast = _timesyncs(s, 3000 * MS, 6000 * MS)
    # three at 5 Hz, then 1 Hz again
    assert fast[:4] == [3000 * MS, 3200 * MS, 3400 * MS, 3600 * MS] and fast[4] == 4600 * MS
    s.autopilot_lost()
    s.autopilot_appeared(1, 1, 8000 * MS)  # back: the fast phase starts again at once
    again = _timesyncs(s, 8000 * MS, 9000 * MS)
    assert again[:3] == [8000 * MS, 8200 * MS, 8400 * MS]


def test_an_accepted_rate_that_does_not_come_is_asked_again_bounded() -> None:
    s = LinkScheduler(_config(stream_rates=(GPS,), rate_verify_s=1.0, rate_max_rerequests=2))
    s.autopilot_appeared(1, 1, 0)
    sent = _run(s, 0, 10_000 * MS)  # GPS_RAW_INT never comes
    assert len(sent) == 3  # the first request and two more
    s.autopilot_appeared(1, 1, 10_000 * MS)  # a new appearance: the bound starts again
    assert len(_run(s, 10_000 * MS, 20_000 * MS)) == 3


def test_an_accepted_rate_that_comes_is_left_alone() -> None:
    s = LinkScheduler(_config(stream_rates=(GPS,), rate_verify_s=1.0))
    s.autopilot_appeared(1, 1, 0)
    sent = []
    for now in range(0, 5000 * MS, 10 * MS):
        due = s.due(now)
        if due.rate is not None:
            sent.append(due.rate)
            s.on_command_ack(_ack(), now + MS)
        if now % (100 * MS) == 0:
            s.counted(GPS.message_id)  # 10 Hz
    assert len(sent) == 1
