"""The scheduler's parts on their own: render on demand and the node table."""

from __future__ import annotations

import pytest

from tessera.balancers.base import Partition, Tile
from tessera.geometry import Camera, Rect
from tessera.scheduling.frame_jobs import FrameJob
from tessera.scheduling.node_table import MAX_NODE_SLOTS, NodeTable
from tessera.scheduling.render_demand import INTERACTIVE, STILL, RenderDemand
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
    owed = []
    for _ in range(4):
        owed.append(demand.owed(0.0, False, True, False))
        if owed[-1]:
            demand.started(still=False)
    assert owed == [INTERACTIVE, INTERACTIVE, None, None]
    assert demand.owed(0.0, False, False, False) is None, "no still frame when they are off"


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
