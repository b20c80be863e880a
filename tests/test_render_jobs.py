"""Render jobs without GL or sockets (issue 35): windows and pieces of a picture, a job's items
in order and handed back, orbits, and the job scheduler on a virtual clock (job tiles after the
sessions' frames, their node time charged to their session, nodes that leave, cancelling)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tessera.balancers.static import StaticBalancer
from tessera.geometry import Camera, Rect
from tessera.scheduling.actions import CancelFrames, PublishFrame, RenderTiles
from tessera.scheduling.job_scheduler import JOB_QUEUE, SHARES_JOB_QUEUE, JobScheduler
from tessera.scheduling.refinement import StillPlan
from tessera.scheduling.render_jobs import (
    DONE,
    LOOKAHEAD,
    MAX_PIECE_SIDE,
    MIN_PIECE_SIDE,
    WHOLE_SIDE,
    WINDOW_MARGIN,
    JobItem,
    JobSpec,
    RenderWork,
    items_of,
    orbit_cameras,
    piece_side,
    pieces,
    window_of,
    windows,
)
from tessera.scheduling.scheduler import SchedulerConfig
from tessera.wire.codec import Codec
from tessera.wire.depth_tiles import DecodedDepthTile
from tessera.wire.protocol import ProtocolError, TileHeader

CAMERA = Camera(eye=(0.0, 1.0, 5.0), target=(0.0, 0.0, 0.0))


def covered(rects: list[Rect], size: tuple[int, int]) -> np.ndarray:
    count = np.zeros((size[1], size[0]), np.int32)
    for rect in rects:
        count[rect.y:rect.y1, rect.x:rect.x1] += 1
    return count


@pytest.mark.parametrize("size", [(640, 480), (4096, 4096), (4097, 100), (8192, 8192), (16384, 9000)])
def test_windows_and_pieces_tile_the_picture_once(size) -> None:
    cells = windows(size)
    assert np.all(covered([cell for cell, _ in cells], size) == 1)
    for cell, window in cells:
        assert window.w <= WHOLE_SIDE + 2 * WINDOW_MARGIN and window.h <= WHOLE_SIDE + 2 * WINDOW_MARGIN
        assert window.x <= cell.x and cell.x1 <= window.x1 and window.y <= cell.y and cell.y1 <= window.y1
        if len(cells) > 1:   # inner edges have a margin, the picture's edges none
            assert window.x == max(cell.x - WINDOW_MARGIN, 0) and window.x1 == min(cell.x1 + WINDOW_MARGIN, size[0])
    for side in (64, 300, 1024):
        cut = pieces(size, side)
        assert np.all(covered([piece for piece, _ in cut], size) == 1)
        assert all(piece.w <= side and piece.h <= side for piece, _ in cut)
        for piece, window in cut:
            assert window_of(piece, size) == window
            assert (window is None) == (len(cells) == 1)


def test_piece_side_follows_the_nodes_rate() -> None:
    assert piece_side(None) == 256
    side = piece_side(1e-3, target_ms=50.0)          # 1 µs a pixel: 50 000 pixels in 50 ms
    assert side % 2 == 0 and side * side <= 50_000 < (side + 2) ** 2
    assert piece_side(1.0) == MIN_PIECE_SIDE and piece_side(1e-9) == MAX_PIECE_SIDE


def test_orbit_turns_about_the_up_axis() -> None:
    cameras = orbit_cameras(CAMERA, 1.0, 8)
    assert cameras[0] == CAMERA and len(cameras) == 8
    for k, camera in enumerate(cameras):
        eye = np.asarray(camera.eye)
        assert math.isclose(eye[1], 1.0) and math.isclose(np.hypot(eye[0], eye[2]), 5.0)
        assert math.isclose(math.atan2(eye[0], eye[2]) % (2 * math.pi), (2 * math.pi * k / 8) % (2 * math.pi),
                            abs_tol=1e-9)


def spec(pictures: int = 1, size=(100, 60), samples: int = 2, kind: str = "poster", session: str = "default"):
    return JobSpec(kind, session, None, [CAMERA] * pictures, size, StillPlan(samples))


def test_items_come_in_order_within_the_lookahead_and_handed_back_ones_first() -> None:
    work = RenderWork("j", spec(pictures=8, samples=2, kind="film"), side=50)
    assert len(work.pieces) == 4 and work.total == 8
    taken = []
    while (item := work.take()) is not None:
        taken.append(item)
    assert taken == list(items_of(work))[:len(taken)]
    assert {item.picture for item in taken} == set(range(LOOKAHEAD + 1)), "no further than the look-ahead"
    work.hand_back(taken[3])
    assert work.take() == taken[3], "a handed-back item goes out again first"
    for item in taken:
        work.drawn(item)
    work.picture_finished(0)
    assert work.done == 1 and work.take() == JobItem(LOOKAHEAD + 1, 0, 0)
    out = work.end("cancelled", "stopped")
    assert work.finished and work.take() is None and not work.waiting and JobItem(LOOKAHEAD + 1, 0, 0) in out
    with pytest.raises(ValueError, match="fixed number"):
        JobSpec("poster", "default", None, [CAMERA], (10, 10), StillPlan(0))


def job_scheduler(nodes: int = 2) -> JobScheduler:
    s = JobScheduler(SchedulerConfig(size=(64, 32), max_fps=1e6, settle_frames=0, still_codec=None),
                     StaticBalancer())
    for node_id in range(1, nodes + 1):
        s.add_node(node_id, 0.0, local=True)
        s.node_ready(node_id, 0.0)
    s.drain()
    return s


def deliver(s: JobScheduler, node_id: int, frame_id: int, now: float, render_ms: float = 5.0) -> list:
    job = s.in_flight[frame_id]
    s.tile_arrived(node_id, TileHeader(frame_id, 0, job.tiles[0].rect, job.codec, render_ms, 1.0, 1.0), b"px", now)
    return s.drain()


def job_tiles(actions) -> dict[int, list[int]]:
    out: dict[int, list[int]] = {}
    for action in actions:
        if isinstance(action, RenderTiles):
            out.setdefault(action.node_id, []).append(action.message.frame)
    return out


def test_job_tiles_fill_free_nodes_after_the_sessions_frames() -> None:
    s = job_scheduler()
    work = RenderWork("j", spec(samples=1), side=50)            # 100x60: 4 pieces
    s.add_job(work, 0.0)
    started = job_tiles(s.drain())
    assert sorted(started) == [1, 2], "each idle node takes a job tile"
    first = s.in_flight[started[1][0]]
    assert first.job == "j" and first.still and first.codec is Codec.RAW and first.size == (100, 60)
    message = first.render_message([0])
    assert message.jitter is None and message.window is None
    s.set_camera(CAMERA, 0.01)               # the session moves: its frame waits for a node, no job tile goes out
    assert not job_tiles(s.drain())
    actions = deliver(s, 1, started[1][0], 0.02, render_ms=7.0)
    assert [a.job.job for a in actions if isinstance(a, PublishFrame)] == ["j"]
    frame = [f for fs in job_tiles(actions).values() for f in fs]
    assert frame and all(s.in_flight[f].job is None for f in frame), "node 1, freed, draws the session's frame"
    assert s.fair.served["default"] == pytest.approx(10.0 + 9.0), "the frame's charge and the job tile's node time"


def test_a_lost_nodes_job_tile_is_drawn_again_and_a_cancelled_job_stops() -> None:
    s = job_scheduler()
    work = RenderWork("j", spec(samples=3), side=50)
    s.add_job(work, 0.0)
    started = job_tiles(s.drain())
    lost = started[2][0]
    lost_item = s.in_flight[lost].item
    s.remove_node(2, 0.1)
    assert lost not in s.in_flight
    assert lost_item in work.again or lost_item in {j.item for j in s.in_flight.values()}, "drawn again"
    kept = next(iter(s.in_flight))
    s.drain()
    s.end_job("j", 0.2)
    actions = s.drain()
    assert not s.in_flight and CancelFrames(1, (kept,)) in actions and work.state == "cancelled"
    assert not job_tiles(actions)


def test_a_job_runs_to_its_end_on_the_scheduler() -> None:
    s = job_scheduler(nodes=3)
    work = RenderWork("j", spec(pictures=3, samples=2, kind="film"), side=50)
    s.add_job(work, 0.0)
    now, drawn = 0.0, []
    actions = s.drain()
    for _ in range(200):
        published = [a.job for a in actions if isinstance(a, PublishFrame)]
        for job in published:
            drawn.append(job.item)
            if work.pieces_done.get(job.item.picture) and len(work.pieces_done[job.item.picture]) == len(work.pieces):
                s.picture_taken("j", job.item.picture, now)
        if not s.in_flight:
            break
        now += 0.01
        frame_id = next(iter(s.in_flight))
        node = s.in_flight[frame_id].tiles[0].node_id
        actions = deliver(s, node, frame_id, now) + s.drain()
    assert sorted(drawn, key=lambda i: (i.picture, i.piece, i.sample)) == list(items_of(work))
    assert work.done == work.total == 3
    s.end_job("j", now, DONE)
    assert "j" not in s.jobs and not s.in_flight


def test_a_dropped_job_tile_that_comes_late_is_ignored_not_refused() -> None:
    s = job_scheduler(nodes=1)
    s.add_job(RenderWork("j", spec(size=(2000, 1000), samples=1), side=512), 0.0)
    frame_id = job_tiles(s.drain())[1][0]
    rect = s.in_flight[frame_id].tiles[0].rect
    assert rect.x1 > 64, "the piece lies outside the session's 64x32 frame"
    s.end_job("j", 0.1)
    s.drain()
    header = TileHeader(frame_id, 0, rect, Codec.RAW, 5.0, 1.0, 1.0)
    assert s.receive_tile(1, header, b"x" * rect.area * 3, 0.2) is None
    with pytest.raises(ProtocolError, match="outside the 2000x1000 picture"):
        s.receive_tile(1, TileHeader(frame_id, 0, Rect(1990, 0, 20, 10), Codec.RAW, 5.0, 1.0, 1.0), b"", 0.3)


def test_nodes_hold_a_bounded_queue_of_job_tiles_that_makes_way_for_a_session_s_frame() -> None:
    """While no session draws, each node holds up to JOB_QUEUE job tiles (never idle between them);
    when the session moves, those no node has begun go back to the job, in order, its frame goes
    to the first node freed, and the film is still drawn whole."""
    s = job_scheduler(nodes=2)
    work = RenderWork("j", spec(pictures=6, samples=1, kind="film"), side=50)   # 4 pieces a picture
    s.add_job(work, 0.0)
    started = job_tiles(s.drain())
    assert {node: len(frames) for node, frames in started.items()} == {1: JOB_QUEUE, 2: JOB_QUEUE}
    heads = {frames[0] for frames in started.values()}
    queued = sorted(f for frames in started.values() for f in frames[1:])
    queued_items = [s.in_flight[f].item for f in queued]
    s.set_camera(CAMERA, 0.01)
    actions = s.drain()
    assert not job_tiles(actions), "the nodes are on their job tiles: the session's frame waits"
    assert set(s.in_flight) == heads, "only the job tiles begun are still out"
    assert {f for a in actions if isinstance(a, CancelFrames) for f in a.frames} == set(queued)
    assert list(work.again) == queued_items, "handed back in order"
    head_of_1 = started[1][0]
    actions = deliver(s, 1, head_of_1, 0.02)
    frame = [f for fs in job_tiles(actions).values() for f in fs]
    assert frame and all(s.in_flight[f].job is None for f in frame), "node 1, freed, draws the session's frame"
    now, drawn, taken = 0.02, [], []
    for _ in range(400):
        for job in [a.job for a in actions if isinstance(a, PublishFrame) and a.job.job == "j"]:
            drawn.append(job.item)
            while len(work.pieces_done.get(len(taken), ())) == len(work.pieces):
                taken.append(len(taken))
                s.picture_taken("j", taken[-1], now)
        assert all(len(node.outstanding) <= JOB_QUEUE for node in s.nodes.values())
        assert len({job.item.picture for job in s.in_flight.values() if job.job}) <= LOOKAHEAD + 1
        if not s.in_flight:
            break
        now += 0.01
        frame_id = next(iter(s.in_flight))
        node = s.in_flight[frame_id].tiles[0].node_id
        actions = deliver(s, node, frame_id, now) + s.drain() if len(s.in_flight[frame_id].tiles) == 1 else \
            [a for t in range(len(s.in_flight[frame_id].tiles)) for a in deliver_tile(s, frame_id, t, now)]
    assert sorted(drawn, key=lambda i: (i.picture, i.piece, i.sample)) == list(items_of(work))
    assert taken == list(range(6)) and work.done == work.total == 6


def test_a_lagging_node_s_job_tile_is_expected_to_take_what_its_piece_took_and_its_queue_goes_back() -> None:
    """A job tile is late by what its piece took in the picture before (not the node's rate in its
    last tile: a film's pieces of background and of the model differ a hundredfold); a node that
    lags has the tile it is on copied to another node and those queued behind it handed back to
    the job (the node skips them), not copied."""
    s = job_scheduler(nodes=2)
    work = RenderWork("j", spec(pictures=4, samples=1, kind="film"), side=50)   # 4 pieces a picture
    s.add_job(work, 0.0)
    started = job_tiles(s.drain())
    costs = {0: 100.0, 1: 2.0, 2: 2.0, 3: 2.0}   # piece 0 is dear, the others cheap
    for now, index in ((0.1, 0), (0.2, 1)):
        for node_id in (1, 2):
            frame_id = started[node_id][index]
            deliver(s, node_id, frame_id, now, render_ms=costs[s.in_flight[frame_id].item.piece])
    queues = {n: [(f, s.in_flight[f].item) for f, _ in s.nodes[n].outstanding] for n in (1, 2)}
    assert [item for _, item in queues[1]] == [JobItem(1, 0, 0), JobItem(1, 2, 0)]
    assert [item for _, item in queues[2]] == [JobItem(1, 1, 0), JobItem(1, 3, 0)]
    assert s.in_flight[queues[1][0][0]].expected_ms == pytest.approx(102.0), "piece 0's time, not the node's rate"
    s.drain()
    s.tick(0.5)   # 0.3 s on their tiles: node 1's piece is expected to take 0.1 s, node 2's 4 ms
    actions = s.drain()
    assert not s.nodes[1].suspect and s.nodes[1].backups == 0, "node 1 is within 4x its piece's time"
    assert s.nodes[2].suspect and s.nodes[2].backups == 1
    (head, _), (queued, queued_item) = queues[2]
    assert job_tiles(actions) == {1: [head]}, "the tile node 2 is on is copied to node 1"
    assert CancelFrames(2, (queued,)) in actions and queued not in s.in_flight, "the one queued is not copied"
    assert list(work.again) == [queued_item], "it goes back to the job"


def deliver_tile(s: JobScheduler, frame_id: int, tile_id: int, now: float) -> list:
    job = s.in_flight[frame_id]
    tile = job.tiles[tile_id]
    s.tile_arrived(tile.node_id, TileHeader(frame_id, tile_id, tile.rect, job.codec, 5.0, 1.0, 1.0), b"px", now)
    return s.drain()


def test_sort_last_job_tiles_go_to_every_share_and_a_new_partition_hands_them_back() -> None:
    """Sort-last: a job tile is one depth tile per share over the same piece, started when every
    holder has room for it (each holds up to SHARES_JOB_QUEUE: a holder ahead does not wait for the others
    at every piece), published once all are in; a node joining (a new data partition) hands the
    tiles in flight back, in order."""
    s = JobScheduler(SchedulerConfig(size=(64, 32), mode="sort-last", max_fps=1e6, settle_frames=0, still_codec=None),
                     StaticBalancer())
    for node_id in (1, 2):
        s.add_node(node_id, 0.0)
    version = s.default.mode.shares.plan.version
    for node_id in (1, 2):
        s.node_ready(node_id, 0.0, version)
    s.drain()
    work = RenderWork("j", spec(samples=2), side=50)
    s.add_job(work, 0.0)
    renders = [a for a in s.drain() if isinstance(a, RenderTiles)]
    frames = [r.message.frame for r in renders if r.node_id == 1]
    assert len(frames) == SHARES_JOB_QUEUE and [r.message.frame for r in renders if r.node_id == 2] == frames
    job = s.in_flight[frames[0]]
    assert [t.rect for t in job.tiles] == [work.pieces[0][0]] * 2 and job.item == JobItem(0, 0, 0)
    assert all(r.message.depth is not None and r.message.depth.share == version for r in renders)
    for k, frame_id in enumerate(frames):   # node 1 runs ahead through its queue
        tile = s.in_flight[frame_id].tiles[0]
        s.tile_arrived(1, TileHeader(frame_id, 0, tile.rect, job.codec, 5.0, 1.0, 1.0, depth=True), b"", 0.1 + k,
                       DecodedDepthTile(version, None, ()))
        actions = s.drain()
        assert not [a for a in actions if isinstance(a, PublishFrame)], "node 2's share is not in"
        assert not [a for a in actions if isinstance(a, RenderTiles)], "node 2 has no room"
    tile = s.in_flight[frames[0]].tiles[1]
    s.tile_arrived(2, TileHeader(frames[0], 1, tile.rect, job.codec, 5.0, 1.0, 1.0, depth=True), b"", 5.0,
                   DecodedDepthTile(version, None, ()))
    actions = s.drain()
    assert [a.job.item for a in actions if isinstance(a, PublishFrame)] == [JobItem(0, 0, 0)]
    renders = [a for a in actions if isinstance(a, RenderTiles)]
    assert sorted(r.node_id for r in renders) == [1, 2] and len({r.message.frame for r in renders}) == 1
    assert all(len(node.outstanding) <= SHARES_JOB_QUEUE for node in s.nodes.values())
    following = sorted(f for f, j in s.in_flight.items() if j.job == "j")
    items = [s.in_flight[f].item for f in following]
    s.add_node(3, 5.1)
    assert not set(following) & set(s.in_flight) and list(work.again) == items, "drawn from the old shares"
    assert not [a for a in s.drain() if isinstance(a, RenderTiles)], "the new shares are not loaded yet"
    for node_id in (1, 2, 3):
        s.node_ready(node_id, 5.2, s.default.mode.shares.plan.version)
    renders = [a for a in s.drain() if isinstance(a, RenderTiles) and s.in_flight[a.message.frame].job == "j"]
    by_node = {n: [r.message.frame for r in renders if r.node_id == n] for n in (1, 2, 3)}
    assert by_node[1] == by_node[2] == by_node[3] and len(by_node[1]) == SHARES_JOB_QUEUE
    assert [s.in_flight[f].item for f in by_node[1]][:len(items)] == items, "the handed-back items first, in order"
