"""The coordinator's frame scheduler in-process on a virtual clock (no sockets, no GL): render on
demand, late camera binding, superseded frames, publish order, push/pull dispatch, node loss."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tessera.balancers import create_balancer
from tessera.balancers.base import BalanceInput, Balancer, Partition, Tile
from tessera.balancers.static import StaticBalancer
from tessera.geometry import Camera, Rect
from tessera.scheduling.actions import BalancerFailed, CancelFrames, CloseNode, LoadScene, PublishFrame, RenderTiles
from tessera.scheduling.node_table import SLOWEST_TRIANGLES_PER_S
from tessera.scheduling.render_demand import SETTLE_GRACE_S
from tessera.scheduling.scheduler import FrameScheduler, SchedulerConfig
from tessera.wire.codec import Codec
from tessera.wire.protocol import ProtocolError, TileHeader

SIZE = (64, 32)


def camera(i: int = 0) -> Camera:
    return Camera(eye=(0.0, 0.0, 5.0 + i), target=(0.0, 0.0, 0.0))


def scheduler(nodes: int = 2, balancer: Balancer | None = None, **config) -> FrameScheduler:
    """A scheduler with ``nodes`` ready nodes (ids 1…N) at t = 0, and no camera yet (no frame-rate
    cap and no settling frames unless given)."""
    config.setdefault("max_fps", 1e6)
    config.setdefault("settle_frames", 0)
    s = FrameScheduler(SchedulerConfig(size=SIZE, **config), balancer or StaticBalancer())
    for node_id in range(1, nodes + 1):
        s.add_node(node_id, 0.0)
        assert s.drain() == [LoadScene(node_id)], "a node that joins is told to load the whole scene"
        s.node_ready(node_id, 0.0)
    return s


def renders(actions) -> dict[int, list[tuple[int, int]]]:
    """node → [(frame, tile), …] of the render messages among ``actions``."""
    out: dict[int, list[tuple[int, int]]] = {}
    for a in actions:
        if isinstance(a, RenderTiles):
            out.setdefault(a.node_id, []).extend((a.message.frame, t.tile) for t in a.message.tiles)
    return out


def published(actions) -> list[int]:
    return [a.job.frame_id for a in actions if isinstance(a, PublishFrame)]


def cancels(actions) -> dict[int, tuple[int, ...]]:
    return {a.node_id: a.frames for a in actions if isinstance(a, CancelFrames)}


def deliver(s: FrameScheduler, node_id: int, frame_id: int, tile_id: int, now: float, rect: Rect | None = None,
            render_ms: float = 5.0):
    """Node ``node_id`` returns the tile it was sent (or ``rect``), drawn in ``render_ms``, with its
    send time; returns the actions."""
    job = s.in_flight.get(frame_id)
    asked = (job.codec, [t.rect for t in job.tiles]) if job else s.retired.get(frame_id, (Codec.JPEG, []))
    codec, rects = asked
    tile_rect = rect or (rects[tile_id] if tile_id < len(rects) else Rect(0, 0, 1, 1))
    s.tile_arrived(node_id, TileHeader(frame_id, tile_id, tile_rect, codec, render_ms, 1.0, 1.0), b"tile", now)
    s.tile_sent(node_id, frame_id, tile_id, 0.5)
    return s.drain()


def finish(s: FrameScheduler, frame_id: int, now: float):
    """Every outstanding tile of ``frame_id`` comes back; returns the actions."""
    actions = []
    for node in list(s.nodes.values()):
        for f, t in [k for k in node.outstanding if k[0] == frame_id]:
            actions += deliver(s, node.node_id, f, t, now)
    return actions


# ------------------------------------------------------------------------------- render on demand


class Drifting(Balancer):
    """Moves its cut one pixel every frame: never settles."""

    name = "drifting"

    def __init__(self) -> None:
        super().__init__()
        self.cut = 16

    def partition(self, inputs: BalanceInput) -> Partition:
        self.cut += 1
        a, b = inputs.node_ids
        return Partition((Tile(Rect(0, 0, self.cut, 32), a), Tile(Rect(self.cut, 0, 64 - self.cut, 32), b)))


def test_nothing_renders_without_a_camera_or_a_ready_node():
    s = scheduler(nodes=0)
    s.set_camera(camera(), 0.0)
    assert s.drain() == [] and not s.in_flight
    s = scheduler(nodes=2)
    assert s.drain() == [] and not s.in_flight, "no camera yet"


def test_a_change_renders_once_then_a_still_frame_then_nothing():
    s = scheduler(still_delay_ms=200)
    assert s.set_camera(camera(), 0.0) == 1
    actions = s.drain()
    assert renders(actions) == {1: [(1, 0)], 2: [(1, 1)]}
    first = s.in_flight[1]
    assert not first.still and first.codec is Codec.JPEG and first.jpeg_quality == 60
    assert published(finish(s, 1, 0.05)) == [1]
    assert s.next_deadline(0.05) == pytest.approx(0.2), "the still frame waits for the quiet period"
    s.tick(0.1)
    assert s.drain() == [] and not s.in_flight
    s.tick(0.2)
    assert renders(s.drain()) == {1: [(2, 0)], 2: [(2, 1)]}
    still = s.in_flight[2]
    assert still.still and still.codec is Codec.PNG and still.camera == first.camera
    assert published(finish(s, 2, 0.3)) == [2]
    assert s.default.settled and s.next_deadline(0.3) is None
    for now in (0.5, 1.0, 10.0):
        s.tick(now)
        assert s.drain() == [] and not s.in_flight, "nothing changed: nothing renders"


def test_no_still_frame_when_still_codec_is_none():
    s = scheduler(still_codec=None)
    s.set_camera(camera(), 0.0)
    finish(s, 1, 0.01)
    s.tick(5.0)
    assert s.drain() == [] and s.default.settled


def test_settling_frames_are_bounded_and_only_while_the_partition_moves():
    s = scheduler(balancer=Drifting(), settle_frames=3, still_codec=None)
    s.set_camera(camera(), 0.0)
    frames, now = 0, 0.0
    for _ in range(10):
        if not s.in_flight and (due := s.next_deadline(now)) is not None:
            assert due >= SETTLE_GRACE_S, "a settle frame waits for the next input a while"
            now = due
            s.tick(now)
        if not s.in_flight:
            break
        now += 0.01
        frames += len(published(finish(s, min(s.in_flight), now)))
    assert frames == 1 + 3, "one frame for the change, then at most settle_frames more"
    steady = scheduler(settle_frames=3, still_codec=None)
    steady.set_camera(camera(0), 0.0)
    finish(steady, 1, 0.01)
    assert not steady.in_flight
    steady.tick(SETTLE_GRACE_S)
    assert list(steady.in_flight) == [2], "a balancer's first partition is compared with its second"
    finish(steady, 2, 0.06)
    steady.tick(0.07)
    assert not steady.in_flight, "the static split does not move: no more settling frames"
    steady.set_camera(camera(1), 0.08)
    finish(steady, 3, 0.09)
    steady.tick(0.08 + SETTLE_GRACE_S)
    assert not steady.in_flight


def test_a_frame_on_one_node_has_no_settling_frame():
    """The whole frame is one node's tile: no edge can move, so no frame is drawn twice (a session
    whose scene one node holds yet drew its first frame again, holding up the other sessions)."""
    s = scheduler(nodes=1, settle_frames=3, still_codec=None)
    s.set_camera(camera(0), 0.0)
    assert list(s.in_flight) == [1]
    finish(s, 1, 0.01)
    assert not s.in_flight, "one tile: nothing to settle"
    s.add_node(2, 0.02)
    s.node_ready(2, 0.02)
    s.set_camera(camera(1), 0.03)
    finish(s, 2, 0.04)
    s.tick(0.03 + SETTLE_GRACE_S)
    assert list(s.in_flight) == [3], "two nodes: the first partition of two tiles is compared with the next"


def test_the_still_frame_is_the_last_frame_even_when_the_partition_moves_again():
    """Steady for the first two frames (settling stops with frames to spare), moving from the still
    frame on: no settling frame may follow the still frame."""

    class MovesLate(Drifting):
        def __init__(self) -> None:
            super().__init__()
            self.calls = 0

        def partition(self, inputs: BalanceInput) -> Partition:
            self.calls += 1
            self.cut = 16 if self.calls <= 2 else self.cut + 1
            a, b = inputs.node_ids
            return Partition((Tile(Rect(0, 0, self.cut, 32), a), Tile(Rect(self.cut, 0, 64 - self.cut, 32), b)))

    s = scheduler(balancer=MovesLate(), settle_frames=3, still_delay_ms=100)
    s.set_camera(camera(), 0.0)
    now, published_still = 0.0, []
    for _ in range(20):
        now += 0.05
        s.tick(now)
        if s.in_flight:
            job = s.in_flight[min(s.in_flight)]
            published_still += [a.job.still for a in finish(s, job.frame_id, now) if isinstance(a, PublishFrame)]
    assert published_still[-1] is True and published_still.count(True) == 1, published_still
    assert s.default.settled and not s.in_flight


def test_balancer_change_and_scene_change_render_again_a_node_join_does_not():
    s = scheduler(still_codec=None)
    s.set_camera(camera(), 0.0)
    finish(s, 1, 0.01)
    s.set_balancer(create_balancer("adaptive"), 1.0)
    assert s.in_flight, "a new balancer renders a frame"
    finish(s, max(s.in_flight), 1.01)
    s.invalidate(2.0)
    assert s.in_flight, "a scene change renders a frame"
    finish(s, max(s.in_flight), 2.01)
    s.add_node(3, 3.0)
    assert not s.in_flight, "a node still loading changes nothing"
    s.node_ready(3, 3.0)
    assert not s.in_flight, "the picture at rest is the same with one more node: nothing is drawn again"
    s.set_camera(camera(1), 4.0)
    frame = max(s.in_flight)
    assert {t.node_id for t in s.in_flight[frame].tiles} == {1, 2, 3}, "the next frame has the new node's tiles"


def test_a_node_joining_while_the_frame_of_the_newest_camera_is_in_flight_does_not_draw_it_twice():
    s = scheduler(still_codec=None)
    s.set_camera(camera(), 0.0)
    frame = max(s.in_flight)
    s.add_node(3, 0.001)
    s.node_ready(3, 0.001)
    assert list(s.in_flight) == [frame], "the frame in flight will show the camera"
    assert published(finish(s, frame, 0.01)) == [frame]
    assert not s.in_flight, "nothing more is owed"


def test_a_node_joining_after_the_only_node_left_mid_frame_draws_the_frame_lost():
    s = scheduler(nodes=1, still_codec=None)
    s.set_camera(camera(), 0.0)
    assert s.in_flight
    s.remove_node(1, 0.01)
    assert not s.in_flight, "no node left: the frame is dropped"
    s.add_node(2, 0.5)
    s.node_ready(2, 0.5)
    assert [t.node_id for t in s.in_flight[max(s.in_flight)].tiles] == [2], "nothing showed the camera yet"


def test_a_node_ready_before_any_frame_starts_the_frame_owed():
    s = scheduler(nodes=0, still_codec=None)
    s.set_camera(camera(), 0.0)
    assert not s.in_flight, "no node holds the scene"
    s.add_node(1, 0.5)
    s.node_ready(1, 0.5)
    assert [t.node_id for t in s.in_flight[max(s.in_flight)].tiles] == [1]


# ------------------------------------------------------------------------ late binding, superseding


def test_a_frame_starts_only_when_a_node_is_free_with_the_newest_camera():
    s = scheduler(max_in_flight=2)
    s.set_camera(camera(0), 0.0)
    s.drain()
    s.set_camera(camera(1), 0.001)
    assert list(s.in_flight) == [1], "both nodes are on frame 1: the newer camera waits"
    s.set_camera(camera(2), 0.002)
    actions = deliver(s, 1, 1, 0, 0.010)
    assert list(s.in_flight) == [1, 2], "node 1 is free: frame 2 starts"
    assert s.in_flight[2].camera == camera(2), "with the newest camera, not the one queued first"
    assert renders(actions) == {1: [(2, 0)], 2: [(2, 1)]}
    assert s.in_flight[2].inputs == {}
    deliver(s, 1, 2, 0, 0.015)
    assert list(s.in_flight) == [1, 2], "two frames in flight at most"


def test_a_frame_begun_by_one_node_is_not_dropped_for_a_newer_camera():
    s = scheduler(max_in_flight=2)
    s.set_camera(camera(0), 0.0)
    s.set_camera(camera(1), 0.001)
    deliver(s, 1, 1, 0, 0.01)
    assert list(s.in_flight) == [1, 2], "node 1 began frame 2; node 2 has it queued behind frame 1"
    s.set_camera(camera(2), 0.011)
    assert list(s.in_flight) == [1, 2] and cancels(s.drain()) == {}, "node 1's work on frame 2 is kept"


def test_a_newer_camera_drops_a_frame_no_node_has_begun():
    s = scheduler(max_in_flight=2)
    s.set_camera(camera(0), 0.0)
    s.set_camera(camera(1), 0.001)
    deliver(s, 1, 1, 0, 0.01)
    s.remove_node(1, 0.012)
    assert list(s.nodes[2].outstanding) == [(1, 1), (2, 1), (2, 0)], "frame 2 now waits behind frame 1"
    s.drain()
    s.set_camera(camera(2), 0.013)
    actions = s.drain()
    assert cancels(actions) == {2: (2,)} and list(s.nodes[2].outstanding) == [(1, 1)]
    assert list(s.in_flight) == [1] and s.frames_cancelled == 1
    actions = deliver(s, 2, 1, 1, 0.02)
    assert published(actions) == [1]
    assert renders(actions) == {2: [(3, 0)]} and s.in_flight[3].camera == camera(2), \
        "node 2 goes straight to the newest camera"


def test_a_still_frame_is_dropped_as_soon_as_the_camera_moves():
    s = scheduler(still_delay_ms=100)
    s.set_camera(camera(0), 0.0)
    finish(s, 1, 0.01)
    s.tick(0.2)
    s.drain()
    assert s.in_flight[2].still
    deliver(s, 1, 2, 0, 0.21)
    s.set_camera(camera(1), 0.22)
    actions = s.drain()
    assert cancels(actions) == {2: (2,)}, "node 2's still tile is cancelled"
    assert 2 not in s.in_flight and list(s.in_flight) == [3]
    assert renders(actions) == {1: [(3, 0)], 2: [(3, 1)]}, "the new camera starts at once"
    assert s.frames_cancelled == 1
    assert deliver(s, 2, 2, 1, 0.25) == [], "the still tile arriving late is dropped quietly"
    assert published(finish(s, 3, 0.3)) == [3]


def test_a_tile_of_a_frame_never_dispatched_is_a_protocol_error():
    s = scheduler()
    s.set_camera(camera(), 0.0)
    with pytest.raises(ProtocolError, match="never dispatched"):
        deliver(s, 1, 7, 0, 0.01)
    with pytest.raises(ProtocolError, match="not assigned"):
        deliver(s, 2, 1, 0, 0.01)



def test_a_tile_a_node_does_not_owe_is_a_protocol_error_even_when_its_frame_is_gone():
    """Fuzz finding (tests/test_fuzz.py): a tile of a published or dropped frame was ignored whoever
    sent it. Only the node that owed it when its frame was dropped may still send it, once."""
    s = scheduler(still_delay_ms=100)
    s.set_camera(camera(0), 0.0)
    finish(s, 1, 0.01)
    with pytest.raises(ProtocolError, match="does not owe"):
        deliver(s, 1, 1, 0, 0.02)  # a second copy of a tile of the published frame
    with pytest.raises(ProtocolError, match="does not owe"):
        deliver(s, 2, 1, 0, 0.02)  # node 1's tile, sent by node 2
    s.tick(0.2)
    s.drain()
    s.set_camera(camera(1), 0.22)
    assert cancels(s.drain()) == {1: (2,), 2: (2,)}, "the still frame is dropped"
    assert deliver(s, 2, 2, 1, 0.23) == [], "the tile node 2 was on when it was dropped: ignored"
    with pytest.raises(ProtocolError, match="does not owe"):
        deliver(s, 2, 2, 1, 0.24)
    with pytest.raises(ProtocolError, match="does not owe"):
        s.tile_failed(2, 2, 1, 0.24)
    s.tiles_skipped(1, 2, [0])
    with pytest.raises(ProtocolError, match="was not dropped"):
        s.tiles_skipped(1, 2, [0])
    assert published(finish(s, 3, 0.3)) == [3], "the others serve on"


def test_a_late_tile_of_a_dropped_frame_is_checked_against_what_was_asked():
    """Fuzz finding: a node's late tile of a frame dropped meanwhile, with another codec or rect
    than its frame asked for, was ignored as any late tile is; it is a protocol error."""
    s = scheduler(still_delay_ms=100)
    s.set_camera(camera(0), 0.0)
    finish(s, 1, 0.01)
    s.tick(0.2)
    s.drain()
    s.set_camera(camera(1), 0.22)
    assert cancels(s.drain()) == {1: (2,), 2: (2,)}, "the still frame is dropped"
    codec, rects = s.retired[2]
    other = next(c for c in Codec if c is not codec)
    with pytest.raises(ProtocolError, match="codec"):
        s.tile_arrived(1, TileHeader(2, 0, rects[0], other, 5.0, 1.0, 1.0), b"tile", 0.23)
    moved = Rect(rects[1].x, rects[1].y, rects[1].w, rects[1].h - 1)
    with pytest.raises(ProtocolError, match="has rect"):
        s.tile_arrived(2, TileHeader(2, 1, moved, codec, 5.0, 1.0, 1.0), b"tile", 0.23)
    assert published(finish(s, 3, 0.3)) == [3], "the others serve on"


def test_the_frame_rate_cap_spaces_frame_starts():
    s = scheduler(max_fps=20.0, max_in_flight=1, still_codec=None)
    s.set_camera(camera(0), 0.0)
    s.set_camera(camera(1), 0.001)
    finish(s, 1, 0.01)
    assert not s.in_flight and s.next_deadline(0.01) == pytest.approx(0.05)
    s.tick(0.05)
    assert s.in_flight[2].camera == camera(1)


# ------------------------------------------------------------------------------- publish order


def test_frames_publish_in_order_and_a_newer_frame_drops_older_ones():
    s = scheduler(nodes=2, balancer=create_balancer("rotate", {"tiles_per_node": 1}), max_in_flight=2)
    s.set_camera(camera(0), 0.0)
    assert renders(s.drain()) == {1: [(1, 0)], 2: [(1, 1)]}, "pull: one tile to each idle node"
    s.set_camera(camera(1), 0.001)
    assert renders(deliver(s, 1, 1, 0, 0.01)) == {1: [(2, 0)]}, "node 1 pulls frame 2's heaviest tile"
    assert renders(deliver(s, 1, 2, 0, 0.02)) == {1: [(2, 1)]}
    actions = deliver(s, 1, 2, 1, 0.03)
    assert published(actions) == [2], "frame 2 is complete before frame 1"
    assert cancels(actions) == {2: (1,)} and 1 not in s.in_flight, "frame 1 can no longer be shown"
    assert deliver(s, 2, 1, 1, 0.04) == [], "its last tile arriving late is dropped quietly"
    assert s.last_published_id == 2 and not s.nodes[2].outstanding


class Harness:
    """A scheduler whose every action is checked: publish order, whole frames, one camera each."""

    def __init__(self, s: FrameScheduler) -> None:
        self.s, self.sent, self.cameras, self.last = s, {}, {}, 0

    def check(self) -> None:
        for a in self.s.drain():
            if isinstance(a, RenderTiles):
                tiles = {(a.message.frame, t.tile) for t in a.message.tiles}
                self.sent.setdefault(a.node_id, set()).update(tiles)
                self.cameras.setdefault(a.message.frame, a.message.camera)
            elif isinstance(a, PublishFrame):
                job = a.job
                assert job.frame_id > self.last, "published backwards"
                self.last = job.frame_id
                assert job.complete, "torn: a tile is missing"
                assert all((job.frame_id, t.tile_id) in self.sent[t.rendered_by] for t in job.tiles)
                assert job.camera == self.cameras[job.frame_id]
        assert len(self.s.in_flight) <= self.s.config.max_in_flight


@settings(max_examples=80, deadline=None)
@given(st.lists(st.tuples(st.sampled_from(["tile", "tile", "tile", "camera", "tick", "leave", "join", "fail"]),
                          st.integers(0, 99)), min_size=1, max_size=150),
       st.sampled_from(["static", "rotate", "adaptive"]), st.integers(1, 3))
def test_never_a_torn_frame_never_backwards_under_random_events(events, balancer_name, in_flight):
    """Random arrivals, failed tiles, camera changes, ticks (stragglers backed up) and nodes leaving
    and joining."""
    s = scheduler(nodes=3, balancer=create_balancer(balancer_name), max_in_flight=in_flight,
                  still_delay_ms=50, settle_frames=2)
    harness = Harness(s)
    now, next_node = 0.0, 4
    s.set_camera(camera(0), now)
    for kind, value in events:
        harness.check()
        now += 0.01
        if kind == "tile":
            owing = [n for n in s.nodes.values() if n.outstanding]
            if owing:
                node = owing[value % len(owing)]
                frame_id, tile_id = next(iter(node.outstanding))
                job = s.in_flight.get(frame_id)
                codec, rects = (job.codec, [t.rect for t in job.tiles]) if job else s.retired[frame_id]
                rect = rects[tile_id]
                s.tile_arrived(node.node_id, TileHeader(frame_id, tile_id, rect, codec, 1.0 + value, 0.1, 0.1),
                               b"t", now)
                s.tile_sent(node.node_id, frame_id, tile_id, 0.1)
        elif kind == "camera":
            s.set_camera(camera(value), now)
        elif kind == "fail":
            owing = [n for n in s.nodes.values() if n.outstanding]
            if owing:
                node = owing[value % len(owing)]
                s.tile_failed(node.node_id, *next(iter(node.outstanding)), now)
        elif kind == "tick":
            now += value * 0.01
            s.tick(now)
        elif kind == "leave" and len(s.nodes) > 1:
            s.remove_node(sorted(s.nodes)[value % len(s.nodes)], now)
        elif kind == "join" and len(s.nodes) < 5:
            s.add_node(next_node, now)
            s.node_ready(next_node, now)
            next_node += 1
    harness.check()


# ------------------------------------------------------------------------------- dispatch


def test_pull_hands_the_heaviest_tile_to_the_fastest_idle_node_first():
    s = scheduler(nodes=3, balancer=create_balancer("rotate", {"tiles_per_node": 2}))
    s.set_speed(1, 1.0)
    s.set_speed(2, 3.0)
    s.set_speed(3, 2.0)
    s.set_camera(camera(), 0.0)
    actions = renders(s.drain())
    job = s.in_flight[1]
    assert job.pull and len(job.tiles) == 6
    assert actions == {2: [(1, 0)], 3: [(1, 1)], 1: [(1, 2)]}, "list order (heaviest first) by node speed"
    assert list(job.pull_queue) == [3, 4, 5]
    actions = deliver(s, 1, 1, 2, 0.01)
    assert renders(actions) == {1: [(1, 3)]}, "the node freed first pulls the next tile"


def test_a_node_lost_mid_frame_has_its_tiles_re_dispatched():
    s = scheduler(nodes=3)
    s.set_camera(camera(), 0.0)
    s.drain()
    deliver(s, 1, 1, 0, 0.01)
    s.remove_node(2, 0.02)
    actions = s.drain()
    assert renders(actions) == {1: [(1, 1)]}, "node 2's tile goes to the idle node 1"
    job = s.in_flight[1]
    deliver(s, 3, 1, 2, 0.03)
    assert published(deliver(s, 1, 1, 1, 0.04)) == [1]
    assert [t.rendered_by for t in job.tiles] == [1, 1, 3]


def test_pulled_tiles_of_a_lost_node_go_back_to_the_front_of_the_queue():
    s = scheduler(nodes=2, balancer=create_balancer("rotate", {"tiles_per_node": 2}))
    s.set_camera(camera(), 0.0)
    s.drain()
    job = s.in_flight[1]
    s.remove_node(2, 0.01)
    assert job.pull_queue[0] == 1 and job.tiles[1].node_id is None
    for step in range(4):
        key = next(iter(s.nodes[1].outstanding))
        actions = deliver(s, 1, *key, 0.02 + step * 0.01)
    assert published(actions) == [1]
    assert {t.rendered_by for t in job.tiles} == {1}


def test_without_ready_nodes_frames_are_dropped_and_a_new_node_renders_again():
    s = scheduler(nodes=1)
    s.set_camera(camera(), 0.0)
    s.drain()
    s.remove_node(1, 0.01)
    assert not s.in_flight and s.frames_cancelled == 1
    s.add_node(9, 0.02)
    s.node_ready(9, 0.03)
    assert renders(s.drain()) == {9: [(2, 0)]}


def test_a_node_that_owes_a_tile_too_long_is_closed_and_its_tile_moves_on():
    s = scheduler(tile_timeout_s=5.0)
    s.set_camera(camera(), 0.0)
    s.drain()
    deliver(s, 1, 1, 0, 0.1)
    assert s.next_deadline(0.1) <= 5.0, "the tile timeout (or an earlier look for stragglers)"
    s.tick(4.0)
    assert s.drain() == []
    s.tick(5.5)
    actions = s.drain()
    assert actions[0] == CloseNode(2, 1011, "tile timeout")
    assert 2 not in s.nodes and renders(actions) == {1: [(1, 1)]}


def test_the_tile_timeout_follows_the_tile_times_measured():
    """A node whose tiles took 12 s each (a share of a huge model) may owe the next for three
    times that, not the 5 s floor; once its tiles are quick again the allowance shrinks back."""
    s = scheduler(tile_timeout_s=5.0, max_in_flight=1, still_codec=None)
    s.set_camera(camera(), 0.0)
    s.drain()
    deliver(s, 1, 1, 0, 12.0)   # no tick came meanwhile: the 5 s floor alone would have closed both
    deliver(s, 2, 1, 1, 12.0)
    s.set_camera(camera(1), 12.0)
    assert renders(s.drain()) == {1: [(2, 0)], 2: [(2, 1)]}
    deliver(s, 1, 2, 0, 13.0)
    s.tick(40.0)   # its tile is backed up on node 1 meanwhile (a straggler), node 2 kept
    assert not [a for a in s.drain() if isinstance(a, CloseNode)] and 2 in s.nodes, "owing for 28 s, within 3 x 12 s"
    assert s.next_deadline(40.0) <= 12.0 + 36.0 + 1e-9
    s.tick(48.5)
    assert s.drain()[0] == CloseNode(2, 1011, "tile timeout"), "owing for 36.5 s, over 3 x 12 s"
    deliver(s, 1, 2, 1, 48.6)   # node 1's copy of it completes frame 2
    node = s.nodes[1]
    assert s.table.allowed_s(node, 5.0) > 5.0
    for step in range(40):   # quick tiles: the longest recent tile time decays
        now = 50.0 + step
        s.set_camera(camera(step + 3), now)
        s.drain()
        for frame_id in sorted(s.in_flight):
            for key in [k for k in node.outstanding if k[0] == frame_id]:
                deliver(s, 1, *key, now + 0.1)
    assert node.tiles_rendered > 30 and s.table.allowed_s(node, 5.0) == 5.0


def test_a_node_holding_a_huge_scene_may_owe_its_first_tile_for_its_triangles():
    """No tile of the scene timed yet: a node that holds 30M triangles is allowed them at the
    slowest rate a node is taken to draw (60 s), not the 5 s floor; a node of a small scene is not."""
    s = scheduler(tile_timeout_s=5.0, max_in_flight=1, still_codec=None)
    s.node_holds(1, 30_000_000)
    s.node_holds(2, 30_000_000)
    s.node_holds(2, 100_000)   # its huge scene closed: what it shows now counts
    assert s.table.allowed_s(s.nodes[1], 5.0) == 30_000_000 / SLOWEST_TRIANGLES_PER_S
    s.set_camera(camera(), 0.0)
    assert renders(s.drain()) == {1: [(1, 0)], 2: [(1, 1)]}
    s.tick(30.0)
    assert [a for a in s.drain() if isinstance(a, CloseNode)] == [CloseNode(2, 1011, "tile timeout")]
    assert 1 in s.nodes, "owing for 30 s of the 60 s its triangles allow"
    s.tick(61.0)
    assert CloseNode(1, 1011, "tile timeout") in s.drain()


def test_slots_are_small_and_reused():
    s = scheduler(nodes=0)
    assert [s.add_node(n, 0.0).slot for n in (10, 11, 12)] == [0, 1, 2]
    s.remove_node(11, 0.0)
    assert s.add_node(300, 0.0).slot == 1
    with pytest.raises(ValueError, match="already"):
        s.add_node(10, 0.0)


# ------------------------------------------------------------------------------- inputs, stats


def test_frames_carry_each_viewers_newest_input_number():
    s = scheduler()
    s.set_camera(camera(0), 0.0, source=1, seq=5)
    assert s.in_flight[1].inputs == {1: 5}
    s.set_camera(camera(1), 0.001, source=2, seq=40)
    s.set_camera(camera(2), 0.002, source=1, seq=6)
    finish(s, 1, 0.01)
    assert s.in_flight[2].inputs == {1: 6, 2: 40}
    s.default.forget_source(2)
    finish(s, 2, 0.02)
    s.set_camera(camera(3), 0.03, source=1, seq=7)
    assert s.in_flight[3].inputs == {1: 7}


def test_latency_is_input_to_publish_of_the_first_frame_showing_it():
    s = scheduler(still_delay_ms=100, settle_frames=0)
    s.set_camera(camera(0), 1.0)
    finish(s, 1, 1.04)
    s.tick(1.2)
    finish(s, max(s.in_flight), 1.3)
    assert s.default.stats.frames_published == 2
    assert s.default.stats.latency_ms == pytest.approx(40.0), "the still frame adds no latency sample"


def test_a_failing_balancer_falls_back_to_the_static_split():
    class Broken(Balancer):
        name = "broken"

        def partition(self, inputs: BalanceInput) -> Partition:
            a, b = inputs.node_ids
            return Partition((Tile(Rect(0, 0, 40, 32), a), Tile(Rect(30, 0, 34, 32), b)))

    s = scheduler(balancer=Broken())
    s.set_camera(camera(), 0.0)
    assert [t.rect for t in s.in_flight[1].tiles] == [Rect(0, 0, 32, 32), Rect(32, 0, 32, 32)]
    failures = [a.reason for a in s.drain() if isinstance(a, BalancerFailed)]
    assert len(failures) == 1 and "exactly once" in failures[0]


def test_the_next_frame_is_partitioned_with_the_frame_that_just_completed():
    """One frame in flight: the last tile's arrival starts the next frame, before its send time is in."""
    seen = []

    class Recording(StaticBalancer):
        def partition(self, inputs: BalanceInput) -> Partition:
            seen.append(inputs.timings)
            return super().partition(inputs)

    s = scheduler(balancer=Recording(), max_in_flight=1, still_codec=None)
    s.set_camera(camera(0), 0.0)
    s.set_camera(camera(1), 0.001)
    for node_id, tile_id in ((1, 0), (2, 1)):
        s.tile_arrived(node_id, TileHeader(1, tile_id, s.in_flight[1].tiles[tile_id].rect, Codec.JPEG, 7.0, 1.0, 1.0),
                       b"t", 0.01)
    assert 2 in s.in_flight and len(seen) == 2
    assert [(t.node_id, t.render_ms) for t in seen[1]] == [(1, 7.0), (2, 7.0)]
