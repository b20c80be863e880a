"""The coordinator's pure bookkeeping: frames in flight, published frames, rolling stats."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest

from server.frame_store import FrameStore, PublishedFrame, paste_tiles
from tessera.balancers.base import Partition, Tile
from tessera.balancers.partition import equal_strip_partition
from tessera.geometry import Camera, Rect
from tessera.scheduling.frame_jobs import FrameJob, check_payload_size
from tessera.scheduling.frame_stats import WINDOW_FRAMES, FrameStats
from tessera.wire.codec import Codec, encode
from tessera.wire.messages import TO_NODE, parse
from tessera.wire.protocol import ProtocolError, TileHeader, unpack_frame

CAMERA = Camera(eye=(0.0, 1.0, 5.0), target=(0.0, 0.0, 0.0), fovy_deg=40.0)
SIZE = (64, 32)
RECTS = (Rect(0, 0, 32, 32), Rect(32, 0, 32, 16), Rect(32, 16, 32, 16))
PUSH = Partition((Tile(RECTS[0], 7), Tile(RECTS[1], 3), Tile(RECTS[2], 7)))
PULL = Partition(tuple(Tile(r, None) for r in RECTS), pull=True)


def image(width: int, height: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (height, width, 3), dtype=np.uint8)


def new_job(partition: Partition = PUSH, codec: Codec = Codec.PNG, frame_id: int = 11) -> FrameJob:
    return FrameJob.create(frame_id, CAMERA, SIZE, codec, 80, partition, started_at=100.0)


def result(job: FrameJob, tile_id: int, *, rect: Rect | None = None, codec: Codec | None = None,
           payload: bytes | None = None, times: tuple[float, float, float] = (4.0, 1.0, 2.0)):
    """A (header, payload) a node would send for ``tile_id``, correct unless told otherwise."""
    rect = rect or job.tiles[tile_id].rect
    codec = codec or job.codec
    if payload is None:
        payload = encode(image(rect.w, rect.h, tile_id), codec)
    return TileHeader(job.frame_id, tile_id, rect, codec, *times), payload


# --------------------------------------------------------------------------------------- frame jobs


def test_create_for_a_push_partition_assigns_tiles_to_their_nodes():
    job = new_job()
    assert not job.pull and list(job.pull_queue) == []
    assert [(t.tile_id, t.rect, t.node_id) for t in job.tiles] == [(0, RECTS[0], 7), (1, RECTS[1], 3),
                                                                   (2, RECTS[2], 7)]
    assert job.owed_by(7) == [0, 2] and job.owed_by(3) == [1] and job.owed_by(4) == []
    assert not job.complete and not job.timings_complete


def test_create_for_a_pull_partition_queues_every_tile_unassigned():
    job = new_job(PULL)
    assert job.pull and list(job.pull_queue) == [0, 1, 2]
    assert all(t.node_id is None for t in job.tiles)
    assert job.owed_by(7) == []


def test_accept_records_the_result_and_completes_the_frame():
    job = new_job()
    for node, tile_id in ((7, 2), (3, 1), (7, 0)):
        header, payload = result(job, tile_id)
        tile = job.accept(node, header, payload)
        assert tile is job.tiles[tile_id]
        assert (tile.rendered_by, tile.header, tile.payload) == (node, header, payload)
    assert job.complete and job.owed_by(7) == [] and job.owed_by(3) == []


def test_owed_by_shrinks_as_tiles_arrive():
    job = new_job()
    job.accept(7, *result(job, 0))
    assert job.owed_by(7) == [2] and not job.complete


def wrong_size(codec: Codec) -> bytes:
    return encode(image(31, 32), codec)


@pytest.mark.parametrize(("node", "tile_id", "changes", "fragment"), [
    pytest.param(3, 0, {}, "not assigned", id="other-nodes-tile"),
    pytest.param(99, 1, {}, "not assigned", id="unknown-node"),
    pytest.param(7, 0, {"rect": Rect(0, 0, 32, 31)}, "rect", id="wrong-rect"),
    pytest.param(7, 0, {"rect": Rect(1, 0, 32, 32)}, "rect", id="shifted-rect"),
    pytest.param(7, 0, {"codec": Codec.JPEG}, "codec", id="wrong-codec"),
])
def test_accept_rejects_what_the_node_does_not_owe(node, tile_id, changes, fragment):
    job = new_job()
    with pytest.raises(ProtocolError, match=fragment):
        job.accept(node, *result(job, tile_id, **changes))
    assert not any(t.done for t in job.tiles) and job.owed_by(7) == [0, 2]


def test_accept_rejects_a_tile_the_frame_does_not_have():
    job = new_job()
    header = TileHeader(job.frame_id, 3, RECTS[0], Codec.PNG, 1.0, 1.0, 1.0)
    with pytest.raises(ProtocolError, match="no tile 3"):
        job.accept(7, header, encode(image(32, 32), Codec.PNG))


@pytest.mark.parametrize(("codec", "payload", "fragment"), [
    pytest.param(Codec.PNG, wrong_size(Codec.PNG), "31x32, expected 32x32", id="png-wrong-size"),
    pytest.param(Codec.PNG, encode(image(32, 33), Codec.PNG), "32x33", id="png-too-tall"),
    pytest.param(Codec.PNG, encode(image(32, 32), Codec.JPEG), "JPEG, expected PNG", id="jpeg-as-png"),
    pytest.param(Codec.PNG, b"\x89PNG not really", "not a readable PNG", id="png-garbage"),
    pytest.param(Codec.PNG, b"", "not a readable PNG", id="empty"),
    pytest.param(Codec.JPEG, encode(image(32, 31), Codec.JPEG), "32x31, expected 32x32", id="jpeg-wrong-size"),
    pytest.param(Codec.JPEG, encode(image(32, 32), Codec.PNG), "PNG, expected JPEG", id="png-as-jpeg"),
    pytest.param(Codec.JPEG, b"\xff\xd8\xff\xe0garbage", "not a readable JPEG", id="jpeg-garbage"),
    pytest.param(Codec.RAW, bytes(32 * 32 * 3 - 1), "raw tile", id="raw-short"),
    pytest.param(Codec.RAW, bytes(32 * 32 * 3 + 3), "raw tile", id="raw-long"),
    pytest.param(Codec.RAW, b"", "raw tile", id="raw-empty"),
])
def test_payload_size_check_reads_only_the_image_header(codec, payload, fragment):
    with pytest.raises(ProtocolError, match=fragment):
        check_payload_size(payload, codec, Rect(0, 0, 32, 32))


@pytest.mark.parametrize("codec", list(Codec))
def test_payload_size_check_accepts_the_right_size(codec):
    check_payload_size(encode(image(32, 16), codec), codec, Rect(5, 7, 32, 16))


def test_accept_refuses_a_duplicate():
    job = new_job()
    job.accept(7, *result(job, 0))
    first = job.tiles[0].payload
    with pytest.raises(ProtocolError, match="already received"):
        job.accept(7, *result(job, 0, payload=encode(image(32, 32, seed=5), Codec.PNG)))
    assert job.tiles[0].payload is first


def test_pull_tiles_are_accepted_only_from_the_node_they_were_handed_to():
    job = new_job(PULL)
    with pytest.raises(ProtocolError, match="not assigned"):
        job.accept(7, *result(job, 0))
    handed_out = job.pull_queue.popleft()
    job.tiles[handed_out].node_id = 7
    job.accept(7, *result(job, handed_out))
    assert job.tiles[0].rendered_by == 7 and not job.complete


def test_timings_complete_needs_every_send_time_from_the_renderer():
    job = new_job()
    for node, tile_id in ((7, 0), (3, 1), (7, 2)):
        job.accept(node, *result(job, tile_id))
    assert job.complete and not job.timings_complete
    job.record_send(3, 0, 9.0)   # node 3 did not render tile 0: ignored
    job.record_send(7, 5, 9.0)   # no such tile: ignored
    job.record_send(7, 0, 1.5)
    job.record_send(3, 1, 2.5)
    assert job.tiles[0].send_ms == 1.5 and not job.timings_complete
    job.record_send(7, 2, 0.0)
    assert job.timings_complete


def test_send_times_before_the_tile_are_ignored():
    job = new_job()
    job.record_send(7, 0, 3.0)
    assert job.tiles[0].send_ms is None


def test_timings_are_attributed_to_the_node_that_rendered_each_tile():
    job = new_job(PULL)
    renderers = {0: 7, 1: 3, 2: 5}   # tile 2 was handed to node 5 after its first owner left
    for tile_id, node in renderers.items():
        job.tiles[tile_id].node_id = node
        job.accept(node, *result(job, tile_id, times=(10.0 * (tile_id + 1), 1.0, 0.5)))
        job.record_send(node, tile_id, 0.25 * (tile_id + 1))
    timings = job.timings()
    assert [(t.rect, t.node_id) for t in timings] == [(RECTS[i], renderers[i]) for i in range(3)]
    assert [(t.render_ms, t.readback_ms, t.encode_ms, t.send_ms) for t in timings] == [
        (10.0, 1.0, 0.5, 0.25), (20.0, 1.0, 0.5, 0.5), (30.0, 1.0, 0.5, 0.75)]
    assert timings[2].busy_ms == 32.25


def test_readback_by_node_lists_the_tiles_each_node_rendered():
    job = new_job()
    for node, tile_id in ((7, 0), (3, 1), (7, 2)):
        job.accept(node, *result(job, tile_id))
    assert job.readback_by_node() == {7: [RECTS[0].as_list(), RECTS[2].as_list()], 3: [RECTS[1].as_list()]}


def test_render_message_carries_the_camera_size_codec_and_tiles():
    job = new_job(codec=Codec.JPEG)
    message = job.render_message([2, 0])
    assert message.to_json() == {
        "type": "render", "frame": 11, "camera": CAMERA.to_json(), "size": [64, 32], "codec": "jpeg",
        "jpeg_quality": 80, "tiles": [{"tile": 2, "rect": [32, 16, 32, 16]}, {"tile": 0, "rect": [0, 0, 32, 32]}],
    }
    parsed = parse(message.to_text(), TO_NODE)
    assert parsed == message and parsed.camera == CAMERA


# -------------------------------------------------------------------------------------- frame store


def published(frame_id: int, tiles: list | None = None, size: tuple[int, int] = SIZE) -> PublishedFrame:
    return PublishedFrame(frame_id, CAMERA, size, tiles or [], published_at=float(frame_id))


@pytest.mark.parametrize("codecs", [[Codec.PNG], [Codec.RAW], [Codec.PNG, Codec.RAW]])
def test_composite_of_lossless_tiles_is_the_original_image(codecs):
    original = image(61, 37, seed=3)
    rects = equal_strip_partition(7, (61, 37))
    tiles = [(r, codecs[i % len(codecs)], i, encode(original[r.y:r.y1, r.x:r.x1], codecs[i % len(codecs)]))
             for i, r in enumerate(rects)]
    np.testing.assert_array_equal(paste_tiles(published(1, tiles, (61, 37))), original)


def test_viewer_message_parses_back():
    original = image(64, 32, seed=4)
    tiles = [(r, codec, node, encode(original[r.y:r.y1, r.x:r.x1], codec))
             for r, codec, node in zip(RECTS, (Codec.PNG, Codec.RAW, Codec.JPEG), (7, 300, 0), strict=True)]
    frame = unpack_frame(published(42, tiles).viewer_message)
    assert (frame.frame_id, frame.size, frame.still, frame.input_seq) == (42, SIZE, False, 0)
    assert [(e.rect, e.codec, e.node, payload) for e, payload in frame.tiles] == tiles


def test_each_viewer_gets_the_input_number_it_sent_and_the_still_flag():
    tiles = [(RECTS[0], Codec.RAW, 2, bytes(32 * 32 * 3))]
    frame = PublishedFrame(9, CAMERA, SIZE, tiles, 0.0, still=True, inputs={1: 77, 2: 4_000_000_000})
    first, second, third = (unpack_frame(frame.message_for(v)) for v in (1, 2, 3))
    assert (first.input_seq, second.input_seq, third.input_seq) == (77, 4_000_000_000, 0)
    assert first.still and second.still and third.still
    assert first.tiles == second.tiles == third.tiles == unpack_frame(frame.viewer_message).tiles


def test_store_keeps_the_newest_frames_up_to_capacity():
    async def scenario() -> None:
        store = FrameStore(capacity=3)
        assert store.latest is None and store.last_id == -1 and store.first_at_or_after(0) is None
        for frame_id in (1, 2, 4, 5, 6):
            store.add(published(frame_id))
        assert store.last_id == 6 and store.latest.frame_id == 6
        assert store.first_at_or_after(0).frame_id == 4, "frames 1 and 2 were evicted"
        assert store.first_at_or_after(5).frame_id == 5
        assert store.first_at_or_after(7) is None

    asyncio.run(scenario())


def test_wait_for_returns_the_first_kept_frame_at_or_after_k():
    async def scenario() -> None:
        store = FrameStore()
        for frame_id in (3, 5, 8):
            store.add(published(frame_id))
        assert (await store.wait_for(4, timeout=5.0)).frame_id == 5
        assert (await store.wait_for(0, timeout=5.0)).frame_id == 3
        assert (await store.wait_for(8, timeout=5.0)).frame_id == 8

    asyncio.run(scenario())


def test_wait_for_waits_until_a_late_enough_frame_is_added():
    async def scenario() -> None:
        store = FrameStore()
        store.add(published(1))
        waiter = asyncio.create_task(store.wait_for(5, timeout=30.0))
        for _ in range(3):
            await asyncio.sleep(0)
        assert not waiter.done()
        store.add(published(4))
        for _ in range(3):
            await asyncio.sleep(0)
        assert not waiter.done(), "frame 4 is too early"
        store.add(published(6))
        frame = await asyncio.wait_for(waiter, timeout=30.0)
        assert frame.frame_id == 6

    asyncio.run(scenario())


def test_wait_for_gives_none_on_timeout():
    async def scenario() -> None:
        store = FrameStore()
        store.add(published(1))
        assert await store.wait_for(2, timeout=0.01) is None

    asyncio.run(scenario())


def test_wait_for_with_no_time_left_still_returns_a_frame_already_kept():
    async def scenario() -> None:
        store = FrameStore()
        store.add(published(1))
        frame = await store.wait_for(1, timeout=0.0)
        assert frame is not None and frame.frame_id == 1

    asyncio.run(scenario())


def test_store_refuses_a_frame_older_than_the_newest():
    store = FrameStore()
    store.add(published(5))
    with pytest.raises(ValueError, match="after frame 5"):
        store.add(published(4))
    assert store.last_id == 5


def test_wait_for_still_skips_interactive_frames():
    async def scenario() -> None:
        store = FrameStore()
        store.add(published(1))
        waiter = asyncio.create_task(store.wait_for(1, timeout=30.0, still=True))
        store.add(published(2))
        for _ in range(3):
            await asyncio.sleep(0)
        assert not waiter.done(), "frames 1 and 2 are interactive"
        store.add(PublishedFrame(3, CAMERA, SIZE, [], 3.0, still=True))
        assert (await asyncio.wait_for(waiter, timeout=30.0)).frame_id == 3
        assert (await store.wait_for(0, timeout=0.0)).frame_id == 1
        assert (await store.wait_for(0, timeout=0.0, still=True)).frame_id == 3

    asyncio.run(scenario())


# -------------------------------------------------------------------------------------------- stats


def test_fps_is_measured_over_the_recent_window():
    stats = FrameStats()
    assert stats.fps(0.0) == 0.0
    for i in range(100):
        stats.record_publish(now=i * 0.05, latency_s=0.010 + 0.001 * (i % 2))
    assert stats.frames_published == 100
    assert stats.fps(now=99 * 0.05) == pytest.approx(20.0)
    assert stats.fps(now=99 * 0.05 + 2.5) == 0.0, "idle for more than 2 s"
    assert stats.latency_ms == pytest.approx(10.5)
    stats.record_publish(now=5.0, latency_s=None)
    assert stats.frames_published == 101 and stats.latency_ms == pytest.approx(10.5), "re-renders add no latency"


def test_imbalance_last_and_average_over_the_window():
    stats = FrameStats()
    assert stats.imbalance == 1.0 and stats.imbalance_avg == 1.0
    stats.record_balance({1: 10.0, 2: 30.0})
    stats.record_balance({1: 10.0, 2: 10.0})
    assert stats.imbalance == 1.0 and stats.imbalance_avg == pytest.approx(1.25)
    for _ in range(WINDOW_FRAMES):
        stats.record_balance({1: 20.0, 2: 60.0})
    assert stats.imbalance_avg == pytest.approx(1.5), "old frames leave the window"
    stats.reset_imbalance()
    assert stats.imbalance_avg == 1.0


def test_node_counters_are_summed_per_frame_and_text_keeps_the_last_value():
    rects = [Rect(0, 0, 2, 2), Rect(2, 0, 2, 2), Rect(0, 2, 4, 2)]
    partition = Partition(tuple(Tile(r, node) for r, node in zip(rects, (7, 7, 9), strict=True)))
    job = FrameJob.create(1, Camera(eye=(0, 0, 3), target=(0, 0, 0)), (4, 4), Codec.RAW, 85, partition, 0.0)
    for tile_id, (rect, node) in enumerate(zip(rects, (7, 7, 9), strict=True)):
        header = TileHeader(1, tile_id, rect, Codec.RAW, 1.0, 0.1, 0.2)
        job.accept(node, header, bytes(rect.w * rect.h * 3))
        job.record_send(node, tile_id, 0.5, {"triangles": 100 * (tile_id + 1), "cull_path": f"p{tile_id}"})
    assert job.counters_by_node() == {7: {"triangles": 300, "cull_path": "p1"},
                                      9: {"triangles": 300, "cull_path": "p2"}}


@pytest.mark.parametrize("codec", [Codec.JPEG, Codec.PNG])
def test_payload_check_decodes_so_a_truncated_image_is_refused_on_arrival(codec):
    payload = encode(image(48, 32, seed=9), codec)
    check_payload_size(payload, codec, Rect(0, 0, 48, 32))
    with pytest.raises(ProtocolError, match="not a readable"):
        check_payload_size(payload[: len(payload) * 2 // 3], codec, Rect(0, 0, 48, 32))
