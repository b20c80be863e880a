"""The frame scheduler on a virtual clock (no sockets, no GL): stragglers backed up on other nodes
(the first copy back wins, never to a node that still owes the tile; a late copy teaches the
node's pace) and failed tiles."""

from __future__ import annotations

import pytest

from tessera.scheduling.actions import CloseNode
from tessera.scheduling.scheduler import FrameScheduler
from tessera.wire.protocol import ProtocolError
from tests.test_scheduler import SIZE, camera, deliver, finish, published, renders, scheduler


def second_frame_out(nodes: int) -> FrameScheduler:
    """``nodes`` nodes that rendered frame 1 (5 + 1 + 1 ms a tile, so each knows its rate); frame 2
    is out and node 1 has answered its tile."""
    s = scheduler(nodes=nodes, backup_floor_s=0.25, backup_factor=4.0, still_codec=None)
    s.set_camera(camera(0), 0.0)
    finish(s, 1, 0.01)
    s.set_camera(camera(1), 0.02)
    s.drain()
    deliver(s, 1, 2, 0, 0.03)
    return s


def frozen_node_scheduler() -> FrameScheduler:
    """3 nodes as :func:`second_frame_out`, node 3 answered frame 2 too and node 2 has not."""
    s = second_frame_out(3)
    deliver(s, 3, 2, 2, 0.03)
    return s


def test_a_straggler_s_tiles_are_copied_to_the_others_and_it_gets_no_new_work():
    s = frozen_node_scheduler()
    s.tick(0.1)
    assert renders(s.drain()) == {} and not s.nodes[2].suspect, "within the floor: no backup yet"
    s.tick(0.4)
    actions = s.drain()
    assert s.nodes[2].suspect and s.backups == 1
    assert renders(actions) == {1: [(2, 1)]}, "node 2's tile goes to the least loaded other node"
    assert published(deliver(s, 1, 2, 1, 0.45)) == [2]
    s.set_camera(camera(2), 0.5)
    assert {t.node_id for t in s.in_flight[3].tiles} == {1, 3}, "the suspect node is left out"
    s.drain()
    assert deliver(s, 2, 2, 1, 0.6) == [], "its late copy is dropped quietly"
    assert not s.nodes[2].suspect, "a node that answers is trusted again"
    finish(s, 3, 0.7)
    assert s.nodes[2].last_tiles == [], "left out of the latest frame: none of its tiles are that frame's"
    assert sum(w * h for n in s.nodes.values() for _, _, w, h in n.last_tiles) == SIZE[0] * SIZE[1]
    s.set_camera(camera(3), 0.8)
    assert {t.node_id for t in s.in_flight[max(s.in_flight)].tiles} == {1, 2, 3}


def test_a_straggler_s_late_copy_teaches_its_pace_and_its_heavier_share_is_not_backed_up_again():
    s = frozen_node_scheduler()
    s.tick(0.4)
    s.drain()
    deliver(s, 1, 2, 1, 0.45)
    area = s.retired[2][1][1].area
    deliver(s, 2, 2, 1, 0.9, render_ms=2000.0)      # its own copy, late: its share got 400x heavier
    assert s.nodes[2].ms_per_px == pytest.approx(2002.0 / area)
    s.set_camera(camera(2), 1.0)
    assert 2 in renders(s.drain())
    s.tick(1.6)
    assert not s.nodes[2].suspect, "0.6 s is within 4x the pace its late tile showed"


def test_a_backup_never_goes_to_a_node_that_still_owes_the_tile():
    """Node 2 lags on frame 2's tile with frame 3's queued behind: both are copied to node 1; it
    answers the first (trusted again) while node 1 lags on the copy of the second: that copy may
    not go back to node 2, which still owes the tile (it would draw it twice and be closed for
    answering a tile it no longer owed: seen under load in bench.tools film, 'tile 0 of frame 126,
    which this node does not owe')."""
    s = second_frame_out(2)
    s.set_camera(camera(2), 0.04)
    s.drain()
    deliver(s, 1, 3, 0, 0.05)
    assert list(s.nodes[2].outstanding) == [(2, 1), (3, 1)], "frame 3's tile queued behind node 2's late one"
    s.tick(0.4)
    assert s.nodes[2].suspect and renders(s.drain()) == {1: [(2, 1), (3, 1)]}
    deliver(s, 2, 2, 1, 0.41)
    deliver(s, 1, 2, 1, 0.42)
    assert not s.nodes[2].suspect and list(s.nodes[2].outstanding) == [(3, 1)]
    s.tick(2.0)
    assert s.nodes[1].suspect and renders(s.drain()) == {}, "node 2 owes it still: no copy goes there"
    assert published(deliver(s, 2, 3, 1, 2.01)) == [3] and not s.nodes[2].outstanding


def test_a_node_that_freezes_before_finishing_a_frame_is_backed_up_at_the_slowest_known_rate():
    s = scheduler(nodes=3, backup_floor_s=0.25, backup_factor=4.0, still_codec=None)
    s.set_camera(camera(0), 0.0)
    finish(s, 1, 0.01)
    s.add_node(4, 0.02)
    s.node_ready(4, 0.02)
    s.set_camera(camera(1), 0.02)
    s.drain()
    [(frame, tile)] = s.nodes[4].outstanding
    for node_id in (1, 2, 3):
        for f, t in list(s.nodes[node_id].outstanding):
            deliver(s, node_id, f, t, 0.03)
    assert s.nodes[4].ms_per_px is None, "the newcomer has not finished a frame: its rate is unknown"
    s.tick(0.2)
    assert not s.nodes[4].suspect, "within the floor"
    s.tick(0.4)
    assert s.nodes[4].suspect, "overdue against the slowest rate the others have shown"
    assert (frame, tile) in [k for node_id, keys in renders(s.drain()).items() if node_id != 4 for k in keys]


def test_the_first_copy_back_wins():
    s = frozen_node_scheduler()
    s.tick(0.4)
    s.drain()
    assert published(deliver(s, 2, 2, 1, 0.41)) == [2], "the straggler's own copy came first"
    assert 2 not in s.in_flight
    assert deliver(s, 1, 2, 1, 0.42) == [], "the backup copy is dropped"


def test_a_failed_tile_goes_to_another_node_and_repeated_failures_close_the_node():
    s = scheduler(nodes=2, max_tile_failures=2, still_codec=None)
    s.set_camera(camera(0), 0.0)
    s.drain()
    s.tile_failed(2, 1, 1, 0.01)
    assert renders(s.drain()) == {1: [(1, 1)]} and 2 in s.nodes
    with pytest.raises(ProtocolError, match="does not owe"):
        s.tile_failed(2, 1, 1, 0.02)
    assert s.drain() == [], "a failure of a tile it no longer owes is refused, and changes nothing"
    deliver(s, 1, 1, 0, 0.03)
    assert published(deliver(s, 1, 1, 1, 0.04)) == [1]
    s.set_camera(camera(1), 0.05)
    s.drain()
    s.tile_failed(2, 2, 1, 0.06)
    actions = s.drain()
    assert CloseNode(2, 1011, "2 tiles failed in a row") in actions and 2 not in s.nodes
    assert renders(actions) == {1: [(2, 1)]}
