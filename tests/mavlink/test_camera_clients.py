"""ClientTracker: which images a ground station missed while away or before it (re)started, on a fake clock."""

from __future__ import annotations

import math

from icgt.mavlink.camera_clients import ClientTracker, IndexSet, is_unspecified_image_request

S = 1_000_000_000
GCS = (245, 190)


def test_index_set_merges_and_splits() -> None:
    s = IndexSet()
    s.add(range(5, 10))
    s.add(range(0, 3))
    s.add(range(3, 5))
    assert s.spans() == [range(0, 10)]
    s.remove(range(2, 4))
    assert s.spans() == [range(0, 2), range(4, 10)] and len(s) == 8 and 5 in s and 3 not in s


def test_unspecified_request_is_mavsdk_s_form_only() -> None:
    assert is_unspecified_image_request(0.0, 0.0) and is_unspecified_image_request(math.nan, math.nan)
    assert not is_unspecified_image_request(3.0, 0.0) and not is_unspecified_image_request(-1.0, 0.0)
    assert not is_unspecified_image_request(0.0, -1.0)


def test_a_client_back_from_a_drop_gets_what_was_published_while_it_was_away() -> None:
    t = ClientTracker(gap_s=2.5, margin_s=0.5, push_delay_s=0.3)
    t.heard(GCS, 0)
    for i in range(20):  # 2 images a second
        t.published(i, i * S // 2)
        if i % 2 == 0 and i < 8:
            t.heard(GCS, i * S // 2)  # heartbeats while the link is up, the last at 3 s
    assert t.due(9 * S) == []  # nothing until it is heard again
    t.heard(GCS, 10 * S)
    assert t.due(10 * S) == []  # the push waits push_delay_s
    t.published(20, 10 * S + S // 10)  # live, after its return: maybe before it knew the camera again
    assert t.due(10 * S + S // 3) == [range(5, 21)]  # published from 3 s - 0.5 s on, up to the newest
    assert t.due(11 * S) == [] and t.counts["client_returns"] == 1 and t.counts["images_pushed"] == 16


def test_steady_heartbeats_push_nothing() -> None:
    t = ClientTracker()
    for i in range(30):
        t.published(i, i * S // 2)
        t.heard(GCS, i * S // 2)
    assert t.due(100 * S) == [] and t.counts["client_returns"] == 0


def test_a_new_instance_holds_nothing_until_it_asks_and_a_push_is_repeated_once_it_knows_the_camera() -> None:
    t = ClientTracker(push_delay_s=0.3)
    t.heard(GCS, 0)
    for i in range(10):
        t.published(i, i * S)
    t.heard(GCS, 9 * S)  # back after 9 s (a restart): 0..9 less the margin are pushed
    pushed = t.due(10 * S)
    assert pushed == [range(0, 10)]
    t.published(10, 10 * S + S // 2)  # live, but to an instance that does not know the camera yet
    t.discovered(GCS, 11 * S)  # the restarted instance asks for CAMERA_INFORMATION after the push
    # the push again once it can know the camera (1.5 s after its request), with the image published in between
    assert t.due(12 * S) == []
    assert t.due(12 * S + S // 2) == [range(0, 11)]
    t.published(11, 12 * S)  # (delivered live: it was published before the repeated push)
    assert t.take_undelivered(GCS) == []  # every image so far has been pushed to it
    t.discovered(GCS, 30 * S)  # yet another instance, no recent push: nothing is sent unasked ...
    assert t.due(31 * S) == []
    assert t.take_undelivered(GCS) == [range(0, 12)]  # ... but everything is sent when it asks
    assert t.take_undelivered(GCS) == []
