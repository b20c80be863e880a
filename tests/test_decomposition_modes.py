"""The decomposition modes as pure objects (no scheduler, GL or network): what each cuts a frame
into, asks of the nodes, accepts of a tile and shows of a complete frame."""

from __future__ import annotations

import numpy as np
import pytest

from tessera.balancers.base import Partition, Tile
from tessera.balancers.static import StaticBalancer
from tessera.compositing.depth_merge import merge_by_depth
from tessera.compositing.layers import DepthLayer, background_pixel
from tessera.decomposition.hybrid import Hybrid
from tessera.decomposition.modes import MODES, create_mode
from tessera.decomposition.sort_first import SortFirst
from tessera.decomposition.sort_last import SortLast
from tessera.geometry import Camera, Rect
from tessera.scheduling.frame_jobs import FrameJob
from tessera.wire.codec import Codec, decode, encode
from tessera.wire.depth_tiles import encode_depth_tile
from tessera.wire.protocol import NO_NODE_SLOT, ProtocolError, TileHeader

SIZE = (64, 32)
BACKGROUND = background_pixel((0.1, 0.2, 0.3))
CAMERA = Camera(eye=(0.0, 0.0, 5.0), target=(0.0, 0.0, 0.0))
HALVES = Partition((Tile(Rect(0, 0, 32, 32), 1), Tile(Rect(32, 0, 32, 32), 2)))


def mode(name: str, strip: int = 4):
    return create_mode(name, SIZE, StaticBalancer(), BACKGROUND, strip)


def job_of(m, partition: Partition, codec: Codec = Codec.PNG) -> FrameJob:
    return FrameJob.create(1, CAMERA, SIZE, codec, 90, partition, 0.0, depth=m.depth_request(partition))


def layer(rect: Rect, depth: float, value: int) -> DepthLayer:
    """A layer over ``rect`` drawn everywhere at ``depth`` in grey ``value``."""
    return DepthLayer(rect, np.full((rect.h, rect.w, 3), value, np.uint8), np.full((rect.h, rect.w), depth, np.float32),
                      0)


def paste(tiles) -> np.ndarray:
    image = np.zeros((SIZE[1], SIZE[0], 3), np.uint8)
    covered = np.zeros((SIZE[1], SIZE[0]), np.int32)
    for rect, codec, _, data in tiles:
        image[rect.y:rect.y1, rect.x:rect.x1] = decode(data, codec, rect.w, rect.h)
        covered[rect.y:rect.y1, rect.x:rect.x1] += 1
    assert (covered == 1).all(), "the viewer tiles cover the frame exactly once"
    return image


def test_modes_by_name_and_an_unknown_one_is_refused():
    assert [type(mode(name)) for name in MODES] == [SortFirst, Hybrid, SortLast]
    assert [(m.needs_depth, m.tiles_move) for m in map(mode, MODES)] == [(False, True), (True, True), (True, False)]
    with pytest.raises(ValueError, match="unknown mode 'sort-middle'"):
        mode("sort-middle")


def test_sort_first_partitions_with_its_balancer_and_shows_tiles_as_sent():
    m = mode("sort-first")
    partition = m.partition([1, 2], {1: 1.0, 2: 1.0}, 0.0, lambda: None)
    assert partition.rects == [Rect(0, 0, 32, 32), Rect(32, 0, 32, 32)] and m.depth_request(partition) is None
    assert m.describe() == {"mode": "sort-first", "depth_strip": None, "partition": None}
    job = job_of(m, partition)
    pixels = [np.full((32, 32, 3), 40 * (i + 1), np.uint8) for i in range(2)]
    for tile, image in zip(job.tiles, pixels, strict=True):
        header = TileHeader(1, tile.tile_id, tile.rect, Codec.PNG, 1.0, 0.0, 0.0)
        payload = encode(image, Codec.PNG)
        assert m.read_tile(job, header, payload) is None
        job.accept(tile.node_id or 0, header, payload)
    shown = m.viewer_tiles(job, lambda node_id: {1: 7, 2: 8}[node_id or 0])
    assert [slot for _, _, slot, _ in shown] == [7, 8]
    np.testing.assert_array_equal(paste(shown), np.concatenate(pixels, axis=1))


def test_a_plain_tile_whose_bytes_are_not_its_image_is_refused_even_for_a_dropped_frame():
    header = TileHeader(1, 0, Rect(0, 0, 32, 32), Codec.PNG, 1.0, 0.0, 0.0)
    with pytest.raises(ProtocolError, match="not a readable PNG"):
        mode("sort-first").read_tile(None, header, b"not a png")
    with pytest.raises(ProtocolError, match="expected 32x32"):
        mode("hybrid").read_tile(None, header, encode(np.zeros((16, 32, 3), np.uint8), Codec.PNG))


def test_the_hybrid_asks_for_the_whole_partition_and_checks_each_tile_against_its_strip():
    m = mode("hybrid", strip=4)
    request = m.depth_request(HALVES)
    assert request.mode == "hybrid" and list(request.tiles) == HALVES.rects and request.strip == 4
    assert m.describe()["depth_strip"] == 4
    job = job_of(m, HALVES)
    header = TileHeader(1, 0, HALVES.tiles[0].rect, Codec.PNG, 1.0, 0.0, 0.0, depth=True)
    beyond = layer(Rect(0, 0, 40, 32), 0.5, 10)   # reaches 8 px into the neighbour: past the 4 px strip
    payload, _ = encode_depth_tile(beyond, None, Codec.PNG, 90)
    with pytest.raises(ProtocolError):
        m.read_tile(job, header, payload)
    assert m.read_tile(None, header, payload) is None, "a tile of a dropped frame is left to the scheduler"


def test_a_hybrid_frame_shows_each_core_as_sent_and_the_strips_merged_by_depth():
    m = mode("hybrid", strip=4)
    job = job_of(m, HALVES)
    left, right = layer(Rect(0, 0, 36, 32), 0.25, 60), layer(Rect(28, 0, 36, 32), 0.75, 200)
    cores = [Rect(0, 0, 28, 32), Rect(36, 0, 28, 32)]
    for tile, drawn, core in zip(job.tiles, (left, right), cores, strict=True):
        payload, _ = encode_depth_tile(drawn, core, Codec.PNG, 90)
        header = TileHeader(1, tile.tile_id, tile.rect, Codec.PNG, 1.0, 0.0, 0.0, depth=True)
        job.accept(tile.node_id or 0, header, payload, m.read_tile(job, header, payload))
    shown = paste(m.viewer_tiles(job, lambda node_id: node_id or 0))
    expected = merge_by_depth([left, DepthLayer(right.rect, right.color, right.depth, 1)], SIZE, BACKGROUND)
    np.testing.assert_array_equal(shown, expected)
    assert (shown[:, 28:36] == 60).all(), "where both drew, the nearer (left) wins"


def test_sort_last_makes_a_share_per_node_and_starts_only_when_every_share_is_loaded():
    m = mode("sort-last")
    assert not m.can_start and m.describe()["partition"]["pending"]
    loads = m.nodes_changed({1: 1.0, 2: 3.0})
    assert [(node, share.index, share.weights) for node, share in loads.items()] == [(1, 0, (1.0, 3.0)),
                                                                                    (2, 1, (1.0, 3.0))]
    version = loads[1].version
    m.share_loaded(1, version)
    assert not m.can_start
    m.share_loaded(2, version)
    assert m.can_start
    partition = m.partition([1, 2], {1: 1.0, 2: 3.0}, 0.0, lambda: None)
    assert partition.tiles == (Tile(Rect(0, 0, *SIZE), 1), Tile(Rect(0, 0, *SIZE), 2))
    assert m.depth_request(partition).share == version
    assert m.describe()["partition"] == {"version": version, "shares": 2, "pending": False, "holders": [1, 2],
                                         "weights": [1.0, 3.0]}
    again = m.nodes_changed({2: 3.0})
    assert list(again) == [2] and again[2].version > version and not m.can_start, "node 1 left: a new partition"


def test_a_sort_last_frame_is_the_merge_and_a_tile_of_another_partition_is_refused():
    m = mode("sort-last")
    loads = m.nodes_changed({1: 1.0, 2: 1.0})
    for node, share in loads.items():
        m.share_loaded(node, share.version)
    job = job_of(m, m.partition([1, 2], {1: 1.0, 2: 1.0}, 0.0, lambda: None))
    near, far = layer(Rect(8, 8, 16, 16), 0.2, 90), layer(Rect(0, 0, 32, 32), 0.6, 180)
    stale, _ = encode_depth_tile(near, None, Codec.PNG, 90, version=loads[1].version + 1)
    header = TileHeader(1, 0, Rect(0, 0, *SIZE), Codec.PNG, 1.0, 0.0, 0.0, depth=True)
    with pytest.raises(ProtocolError, match="share of partition"):
        m.read_tile(job, header, stale)
    for tile, drawn in zip(job.tiles, (near, far), strict=True):
        payload, _ = encode_depth_tile(drawn, None, Codec.PNG, 90, version=loads[1].version)
        header = TileHeader(1, tile.tile_id, tile.rect, Codec.PNG, 1.0, 0.0, 0.0, depth=True)
        job.accept(tile.node_id or 0, header, payload, m.read_tile(job, header, payload))
    shown = m.viewer_tiles(job, lambda node_id: node_id or 0)
    assert [(rect, slot) for rect, _, slot, _ in shown] == [(Rect(0, 0, *SIZE), NO_NODE_SLOT)]
    expected = merge_by_depth([near, DepthLayer(far.rect, far.color, far.depth, 1)], SIZE, BACKGROUND)
    np.testing.assert_array_equal(paste(shown), expected)
