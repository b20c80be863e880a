"""The scheduler's parts on their own: render on demand and the node table."""

from __future__ import annotations

import pytest

from tessera.balancers.base import Partition, Tile
from tessera.geometry import Camera, Rect
from tessera.scheduling.frame_jobs import FrameJob
from tessera.scheduling.node_table import MAX_NODE_SLOTS, NodeTable
from tessera.scheduling.render_demand import INTERACTIVE, SETTLE_GRACE_S, STILL, RenderDemand
from tessera.wire.codec import Codec
from tessera.wire.protocol import ProtocolError


def test_a_change_owes_one_interactive_frame_then_the_still_after_the_quiet_time():
    demand = RenderDemand(settle_frames=0, still_delay_s=0.2, still_frames=True)
    assert demand.owed(0.0, False, False, False) is None, "nothing changed yet"
    demand.changed(1.0)
    assert demand.owed(1.0, False, False, False) == INTERACTIVE
    demand.started(still=False)
    assert demand.owed(1.1, False, False, False) is None, "rendered; the still waits for quiet"
    assert demand.owed(1.1, False, False, False, ignore_quiet=True) == STILL
    assert demand.quiet_until == pytest.approx(1.2)
    assert demand.owed(1.25, False, False, True) is None, "not while frames are in flight"
    assert demand.owed(1.25, False, False, False) == STILL
    demand.started(still=True)
    assert demand.owed(5.0, False, False, False) is None
    assert demand.owed(5.0, True, False, False) == INTERACTIVE, "a playing animation always owes a frame"


def test_settle_frames_follow_a_change_while_the_partition_moves():
    demand = RenderDemand(settle_frames=2, still_delay_s=0.2, still_frames=False)
    demand.changed(0.0)
    demand.started(still=False)
    assert demand.owed(SETTLE_GRACE_S / 2, False, True, False) is None, "the next input may be on its way"
    assert demand.due(0.0, INTERACTIVE) == SETTLE_GRACE_S
    owed = []
    for _ in range(4):
        owed.append(demand.owed(SETTLE_GRACE_S, False, True, False))
        if owed[-1]:
            demand.started(still=False)
    assert owed == [INTERACTIVE, INTERACTIVE, None, None]
    assert demand.owed(1.0, False, False, False) is None, "no still frame when they are off"
    demand.changed(2.0)
    assert demand.due(2.0, INTERACTIVE) == 2.0, "a change's own frame starts at once"


def test_the_first_frame_of_a_version_is_its_first_answer():
    demand = RenderDemand(settle_frames=0, still_delay_s=0.0, still_frames=True)
    demand.changed(0.0)
    assert demand.published(1) and not demand.published(1) and not demand.published(0)


def test_node_table_slots_readiness_and_owed_tiles():
    table = NodeTable()
    a, b = table.add(1, 0.0), table.add(2, 0.0)
    assert (a.slot, b.slot) == (0, 1) and table.ready() == [] and not table.idle
    with pytest.raises(ValueError, match="already scheduled"):
        table.add(1, 0.0)
    for node in (a, b):
        node.ready = True
        table.touch(node, state_changed=True)
    assert table.ready() == [a, b] and table.idle == {1, 2}
    table.assign(a, [(1, 0), (1, 1)], 0.5)
    assert table.idle == {2} and a.head_since == 0.5 and table.heads(1) and not table.heads(2)
    table.answered(a, (1, 0), 0.7)
    assert a.head_since == 0.7 and list(a.outstanding) == [(1, 1)]
    assert table.drop(a, 1, 0.8) and a.dropped == {(1, 1): None} and table.idle == {1, 2}
    table.skipped(a, 1, [1])
    with pytest.raises(ProtocolError, match="was not dropped"):
        table.skipped(a, 1, [1])
    with pytest.raises(ProtocolError, match="does not owe"):
        table.check_owed(a, (1, 0), "tile")
    table.remove(1)
    assert table.add(3, 1.0).slot == 0, "a freed slot is taken again"
    assert MAX_NODE_SLOTS == 1 << 16


def test_a_node_late_on_its_tile_is_overdue_against_its_own_rate_or_the_slowest_known():
    table = NodeTable()
    fast, fresh = table.add(1, 0.0), table.add(2, 0.0)
    fast.ms_per_px = 0.001                  # 1 ms per 1000 px
    job = FrameJob.create(1, Camera(eye=(0.0, 0.0, 5.0), target=(0.0, 0.0, 0.0)), (100, 100), Codec.JPEG, 60,
                          Partition((Tile(Rect(0, 0, 100, 100), 1), Tile(Rect(0, 0, 100, 100), 2))), 0.0)
    table.assign(fast, [(1, 0)], 0.0)
    table.assign(fresh, [(1, 1)], 0.0)
    expected_s = 0.001 * 100 * 100 / 1000.0   # 10 ms: the floor (0.25 s) rules
    assert table.overdue({1: job}, 4.0, 0.25, 0.2) == []
    assert table.overdue({1: job}, 4.0, 0.25, 0.3) == [fast, fresh], "the newcomer is held to the slowest rate"
    fast.suspect = True
    assert table.overdue({1: job}, 4.0, 0.25, 0.3) == [fresh] and expected_s < 0.25
    assert table.overdue({}, 4.0, 0.25, 9.0) == [], "nothing owed of a frame in flight"


def test_a_node_on_its_last_tile_wants_work_its_round_trip_before_the_tile_ends():
    table = NodeTable()
    node = table.add(1, 0.0)
    node.ready = True
    table.touch(node, state_changed=True)
    camera = Camera(eye=(0.0, 0.0, 5.0), target=(0.0, 0.0, 0.0))
    jobs = {f: FrameJob.create(f, camera, (100, 100), Codec.JPEG, 60, Partition((Tile(Rect(0, 0, 100, 100), 1),)), 0.0)
            for f in (1, 2, 3)}
    table.assign(node, [(1, 0)], 1.0)         # sent while it owed nothing: its round trip is measured
    assert table.wanting_work(jobs, 1.0) == set(), "rate and round trip not measured yet"
    table.answered(node, (1, 0), 1.030, busy_ms=20.0)
    assert node.lead_s == pytest.approx(0.010) and table.wanting_work(jobs, 1.030) == {1}, "idle"
    node.ms_per_px = 0.002                    # 20 ms for the 10 000 px tile
    table.assign(node, [(2, 0)], 1.030)
    table.assign(node, [(3, 0)], 1.031)       # queued behind it: no round trip from this one
    assert table.wanting_work(jobs, 1.045) == set(), "two tiles owed"
    assert table.next_wanting_at(jobs, 1.045) is None
    table.answered(node, (2, 0), 1.065, busy_ms=20.0)
    assert node.lead_s == pytest.approx(0.011), "smoothed: 0.010 + 0.2 × (0.015 − 0.010)"
    wants_at = 1.065 + 0.020 - 0.011         # frame 3's tile began about when frame 2's answer came
    assert table.next_wanting_at(jobs, 1.065) == pytest.approx(wants_at)
    assert table.wanting_work(jobs, wants_at - 1e-6) == set() and table.wanting_work(jobs, wants_at) == {1}
    node.suspect = True
    assert table.wanting_work(jobs, 2.0) == set(), "a suspect node wants no work"
