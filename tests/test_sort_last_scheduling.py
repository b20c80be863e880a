"""Sort-last on the coordinator without sockets or GL (issue 10): data partitions and their versions
(:mod:`tessera.decomposition.share_plan`), and the scheduler in ``sort-last`` mode on a virtual clock: every node
joining or leaving makes a new partition and tells each node its share, frames wait until every
share of it is loaded, a frame is one whole-frame depth tile per share from its holder, frames in
flight when the partition changes are dropped, and nothing moves to a node lacking the share."""

from __future__ import annotations

from tessera.balancers.static import StaticBalancer
from tessera.decomposition.share_plan import ShareBook
from tessera.decomposition.sort_last import SortLast
from tessera.geometry import Camera, Rect
from tessera.scheduling.actions import CancelFrames, LoadScene, PublishFrame, RenderTiles
from tessera.scheduling.scheduler import FrameScheduler, SchedulerConfig
from tessera.wire.codec import Codec
from tessera.wire.depth_tiles import DecodedDepthTile
from tessera.wire.protocol import TileHeader

SIZE = (64, 32)
FRAME = Rect(0, 0, *SIZE)
CAMERA = Camera(eye=(0.0, 0.0, 5.0), target=(0.0, 0.0, 0.0))


def test_share_book_versions_and_completeness():
    book = ShareBook()
    assert not book.complete and book.repartition({}) is None
    plan = book.repartition({3: 1.0, 1: 2.0})
    assert plan is not None and plan.version == 2 and plan.holders == (1, 3) and plan.weights == (2.0, 1.0)
    assert plan.index_of(3) == 1
    assert not book.share_loaded(1, 2) and not book.complete
    assert not book.share_loaded(3, 1), "a share of an older partition does not count"
    assert book.share_loaded(3, 2) and book.complete
    book.forget(3)
    assert not book.complete


def sort_last(nodes: int = 2) -> FrameScheduler:
    s = FrameScheduler(SchedulerConfig(size=SIZE, mode="sort-last", max_fps=1e6, settle_frames=0), StaticBalancer())
    for node_id in range(1, nodes + 1):
        s.add_node(node_id, 0.0)
    return s


def load_shares(s: FrameScheduler, actions, now: float = 0.0) -> list:
    """Every node told to load a share reports it loaded; returns the actions that follow."""
    out = []
    for action in actions:
        if isinstance(action, LoadScene):
            s.node_ready(action.node_id, now, action.share.version)
            out += s.drain()
    return out


def deliver(s: FrameScheduler, node_id: int, frame_id: int, tile_id: int, now: float):
    mode = s.default.mode
    version = mode.shares.plan.version if isinstance(mode, SortLast) and mode.shares.plan else 0
    s.tile_arrived(node_id, TileHeader(frame_id, tile_id, FRAME, Codec.JPEG, 5.0, 1.0, 1.0, depth=True), b"",
                   now, DecodedDepthTile(version, None, ()))
    s.tile_sent(node_id, frame_id, tile_id, 0.5)
    return s.drain()


def test_each_join_makes_a_partition_and_frames_wait_for_every_share():
    s = sort_last(nodes=2)
    actions = s.drain()
    loads = [a for a in actions if isinstance(a, LoadScene)]
    assert [(a.node_id, a.share.version, a.share.index) for a in loads] == [(1, 1, 0), (1, 2, 0), (2, 2, 1)]
    assert all(a.share.weights == (1.0, 1.0) for a in loads[1:])
    s.set_camera(CAMERA, 0.0)
    s.node_ready(1, 0.0, 2)
    assert not [a for a in s.drain() if isinstance(a, RenderTiles)], "share 1 is not loaded yet"
    assert s.next_deadline(0.0) is None, "nothing to wake for until the next share is loaded (no busy timer)"
    s.node_ready(2, 0.0, 1)
    assert not [a for a in s.drain() if isinstance(a, RenderTiles)], "node 2 holds a share of an older partition"
    s.node_ready(2, 0.0, 2)
    renders = [a for a in s.drain() if isinstance(a, RenderTiles)]
    assert [(r.node_id, [t.rect for t in r.message.tiles]) for r in renders] == [(1, [FRAME]), (2, [FRAME])]
    depth = renders[0].message.depth
    assert depth is not None and depth.mode == "sort-last" and depth.share == 2
    done = deliver(s, 1, 1, 0, 0.1) + deliver(s, 2, 1, 1, 0.1)
    assert [a.job.frame_id for a in done if isinstance(a, PublishFrame)] == [1]


def shares_told(actions) -> list[tuple[int, int, int, int]]:
    """(node, partition version, share index, shares) of each LoadScene among ``actions``."""
    return [(a.node_id, a.share.version, a.share.index, len(a.share.weights)) for a in actions
            if isinstance(a, LoadScene)]


def test_expected_nodes_get_their_shares_once_all_joined_not_one_partition_per_join():
    s = FrameScheduler(SchedulerConfig(size=SIZE, mode="sort-last", settle_frames=0), StaticBalancer())
    s.expect_nodes(3, until=20.0)
    s.add_node(1, 0.0)
    s.add_node(2, 0.5)
    assert shares_told(s.drain()) == [], "no share of one, then of two"
    assert s.next_deadline(0.5) == 20.0, "the wait's end wakes the scheduler"
    s.add_node(3, 1.0)
    assert shares_told(s.drain()) == [(1, 1, 0, 3), (2, 1, 1, 3), (3, 1, 2, 3)]
    s.add_node(4, 2.0)
    assert shares_told(s.drain()) == [(1, 2, 0, 4), (2, 2, 1, 4), (3, 2, 2, 4), (4, 2, 3, 4)], \
        "a node beyond those expected joins as before"


def test_when_the_wait_for_expected_nodes_runs_out_those_there_get_shares():
    s = FrameScheduler(SchedulerConfig(size=SIZE, mode="sort-last", settle_frames=0), StaticBalancer())
    s.expect_nodes(3, until=20.0)
    s.add_node(1, 0.0)
    s.add_node(2, 0.5)
    s.tick(19.9)
    assert shares_told(s.drain()) == []
    s.tick(20.0)
    assert shares_told(s.drain()) == [(1, 1, 0, 2), (2, 1, 1, 2)]
    s.add_node(3, 30.0)
    assert shares_told(s.drain()) == [(1, 2, 0, 3), (2, 2, 1, 3), (3, 2, 2, 3)]


def test_a_sort_first_session_loads_as_nodes_join_while_others_are_expected():
    s = FrameScheduler(SchedulerConfig(size=SIZE, settle_frames=0), StaticBalancer())
    s.expect_nodes(3, until=20.0)
    s.add_node(1, 0.0)
    assert [a.node_id for a in s.drain() if isinstance(a, LoadScene)] == [1]


def test_a_node_leaving_drops_the_frames_in_flight_and_repartitions_over_the_others():
    s = sort_last(nodes=3)
    load_shares(s, s.drain())
    s.set_camera(CAMERA, 0.0)
    s.drain()
    assert s.in_flight
    s.remove_node(2, 1.0)
    actions = s.drain()
    assert not s.in_flight and s.frames_cancelled >= 1
    assert set(a.node_id for a in actions if isinstance(a, CancelFrames)) == {1, 3}
    loads = [(a.node_id, a.share.index, len(a.share.weights)) for a in actions if isinstance(a, LoadScene)]
    assert loads == [(1, 0, 2), (3, 1, 2)]
    assert not [a for a in actions if isinstance(a, RenderTiles)], "no frame before the new shares are loaded"
    after = load_shares(s, actions, 2.0)
    renders = [a for a in after if isinstance(a, RenderTiles)]
    assert sorted(r.node_id for r in renders) == [1, 3]
    assert renders[0].message.depth is not None and renders[0].message.depth.share == s.default.mode.shares.plan.version


def test_a_failed_tile_goes_back_to_its_holder_and_stragglers_are_not_backed_up():
    s = sort_last(nodes=2)
    load_shares(s, s.drain())
    s.set_camera(CAMERA, 0.0)
    s.drain()
    s.tile_failed(1, 1, 0, 0.1)
    again = [a for a in s.drain() if isinstance(a, RenderTiles)]
    assert [(a.node_id, a.message.frame, a.message.tiles[0].tile) for a in again] == [(1, 1, 0)]
    for node in s.nodes.values():
        node.ms_per_px = 1e-6
    s.tick(100.0)
    assert s.backups == 0 and not [a for a in s.drain() if isinstance(a, RenderTiles)]


def test_a_share_of_an_older_partition_reported_late_does_not_undo_the_newer_one():
    """Nodes joining one after another make partitions in a row; a node's loads end in any order
    (each share is a load of its own): its late report of an older share leaves the newest complete."""
    book = ShareBook()
    book.repartition({1: 1.0})
    book.repartition({1: 1.0, 2: 1.0})
    plan = book.repartition({1: 1.0, 2: 1.0, 3: 1.0})
    assert plan is not None and plan.version == 3
    assert not book.share_loaded(1, 3) and not book.share_loaded(2, 3)
    assert book.share_loaded(3, 3) and book.complete
    assert not book.share_loaded(1, 1) and not book.share_loaded(2, 2)
    assert book.complete, book.loaded
