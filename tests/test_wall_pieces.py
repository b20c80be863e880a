"""A display wall's cut tiles drawn once (issue 22): the cut names the tile each piece comes from,
the ``render`` message carries it (``part_of``, left out for a whole tile), the coordinator pulls a
tile's pieces together and counts the drawing in a piece's busy time, a node draws the pieces of
one tile as one rect and sends each piece as its own tile, the drawing's times shared out by area
and its counters on the first piece, a failed drawing one failure; a real node's pieces equal its
frame drawn whole."""

from __future__ import annotations

import asyncio
import json

import numpy as np
import pytest
from websockets.asyncio.server import serve

from node.client import NodeClient
from node.gl.renderer import RenderedTile, TileRenderer
from node.protocol import Draw
from node.scene.loading import load_scene
from node.settings import NodeSettings
from node.tile_messages import cut_pieces
from tessera.balancers.base import Partition, Tile
from tessera.decomposition.wall_cells import WallLayout
from tessera.geometry import Camera, Rect
from tessera.scheduling.actions import CloseNode
from tessera.scheduling.frame_jobs import DEFAULT_SESSION, FrameJob
from tessera.wire.codec import Codec, decode
from tessera.wire.messages import InvalidMessage, Render, RenderTile, TilesDropped, parse
from tessera.wire.protocol import TileHeader, unpack_tile
from tests.conftest import seconds
from tests.test_node_client import BACKGROUND, FakeCoordinator, receive, receive_json, send
from tests.test_node_protocol import CAMERA, connected, drain, sent
from tests.test_scheduler import camera, finish, renders, scheduler

#: A 2×2 wall of 40×30 cells, 4 px of bezel; three strips over it, as a 3-node balancer makes them.
WALL = WallLayout(2, 2, (40, 30), (4, 2))
STRIPS = Partition((Tile(Rect(0, 0, 20, 62), 1), Tile(Rect(20, 0, 40, 62), 2), Tile(Rect(60, 0, 24, 62), 3)))


def test_the_cut_names_the_tile_each_piece_comes_from():
    cut, parts = WALL.pieces(STRIPS)
    assert cut == WALL.cut(STRIPS) and len(parts) == len(cut.tiles)
    by_tile: dict[Rect, list[Rect]] = {}
    for tile, part in zip(cut.tiles, parts, strict=True):
        assert part is not None, "every strip crosses a cell edge"
        by_tile.setdefault(part, []).append(tile.rect)
    assert list(by_tile) == [t.rect for t in STRIPS.tiles], "pieces of one tile follow each other"
    for part, rects in by_tile.items():
        assert sum(r.area for r in rects) == part.area
    whole = WallLayout(2, 1, (40, 30)).pieces(Partition((Tile(Rect(0, 0, 40, 30), 1), Tile(Rect(40, 0, 40, 30), 2))))
    assert whole[1] == (None, None), "a tile no edge crosses is whole"


def test_render_tiles_name_their_tile_and_leave_it_out_when_whole():
    render = Render(frame=3, camera=Camera.from_json(CAMERA), size=(84, 62), codec=Codec.PNG,
                    tiles=(RenderTile(tile=0, rect=Rect(0, 0, 20, 30), part_of=Rect(0, 0, 20, 62)),
                           RenderTile(tile=1, rect=Rect(20, 0, 40, 30))))
    data = render.to_json()
    assert data["tiles"] == [{"tile": 0, "rect": [0, 0, 20, 30], "part_of": [0, 0, 20, 62]},
                             {"tile": 1, "rect": [20, 0, 40, 30]}], "a whole tile's JSON is what it was"
    assert parse(render.to_text(), [Render]) == render
    data["tiles"][0]["part_of"] = [0, 0, 10, 62]
    with pytest.raises(InvalidMessage, match="not inside part_of"):
        Render.from_json(data)


def wall_render(frame: int, tiles: list[tuple[list[int], list[int] | None]], depth: dict | None = None) -> str:
    message = {"type": "render", "frame": frame, "camera": CAMERA, "size": [84, 62], "codec": "png",
               "tiles": [{"tile": i, "rect": rect, **({} if part is None else {"part_of": part})}
                         for i, (rect, part) in enumerate(tiles)]}
    if depth is not None:
        message["depth"] = depth
    return json.dumps(message)


STRIP = [20, 0, 40, 62]
#: The middle strip cut into four, a whole tile, then one piece of another strip alone.
PIECES = [([20, 0, 20, 30], STRIP), ([40, 0, 20, 30], STRIP), ([20, 32, 20, 30], STRIP), ([40, 32, 20, 30], STRIP),
          ([20, 30, 40, 2], STRIP), ([0, 0, 20, 62], None), ([60, 0, 24, 30], [60, 0, 24, 62])]


def test_a_node_draws_the_pieces_of_one_tile_as_one_rect():
    draws = [a for a in drain(connected(wall_render(1, PIECES))) if isinstance(a, Draw)]
    assert [(d.tile.tile, d.tile.rect.as_list(), [p.tile for p in d.pieces]) for d in draws] == [
        (0, STRIP, [0, 1, 2, 3, 4]), (5, [0, 0, 20, 62], []), (6, [60, 0, 24, 30], [])]
    assert [[t.tile for t in d.sent] for d in draws] == [[0, 1, 2, 3, 4], [5], [6]]


def test_pieces_that_do_not_fill_one_rect_or_depth_tiles_are_drawn_each_alone():
    gap = [PIECES[0], PIECES[3]]   # two corners of the strip: their bounding rect holds pixels of neither
    draws = [a for a in drain(connected(wall_render(1, gap))) if isinstance(a, Draw)]
    assert [(d.tile.tile, d.pieces) for d in draws] == [(0, ()), (1, ())]
    depth = {"mode": "hybrid", "tiles": [[0, 0, 84, 62]], "strip": 0}
    draws = [a for a in drain(connected(wall_render(2, PIECES[:2], depth))) if isinstance(a, Draw)]
    assert [(d.tile.tile, d.pieces) for d in draws] == [(0, ()), (1, ())]


def test_a_cancel_drops_every_piece_of_a_tile_not_begun():
    protocol = connected(wall_render(4, PIECES))
    first = protocol.next_action()
    assert isinstance(first, Draw) and len(first.sent) == 5
    protocol.receive_text(json.dumps({"type": "cancel", "frames": [4]}))
    assert sent(drain(protocol)) == [TilesDropped(frame=4, tiles=(5, 6))]
    protocol = connected(json.dumps({"type": "cancel", "frames": [5]}), wall_render(5, PIECES))
    assert sent(drain(protocol)) == [TilesDropped(frame=5, tiles=tuple(range(7)))]


def rendered_tile(rect: Rect) -> RenderedTile:
    pixels = np.random.default_rng(1).integers(0, 256, (rect.h, rect.w, 3), dtype=np.uint8)
    return RenderedTile(rect, pixels, 12.0, 3.0, 500, 7, 9, 0.5, "cpu")


def test_cut_pieces_share_one_drawing_out_by_area():
    drawing = rendered_tile(Rect(20, 0, 40, 62))
    pieces = [RenderTile(tile=i, rect=Rect(*rect), part_of=Rect(*STRIP)) for i, (rect, _) in enumerate(PIECES[:5])]
    out = cut_pieces(drawing, 24.0, pieces)
    for piece, (tile, render_ms) in zip(pieces, out, strict=True):
        r = piece.rect
        assert tile.rect == r and np.array_equal(tile.pixels, drawing.pixels[r.y:r.y1, r.x - 20:r.x1 - 20])
        assert render_ms == pytest.approx(24.0 * r.area / (40 * 62))
    assert sum(ms for _, ms in out) == pytest.approx(24.0) and sum(t.readback_ms for t, _ in out) == pytest.approx(3.0)
    assert out[0][0].stats() == drawing.stats(), "the drawing's counters, once"
    assert all(t.triangles == t.chunks_drawn == t.chunks_culled == 0 and t.cull_ms == 0.0 for t, _ in out[1:])
    ((alone, alone_ms),) = cut_pieces(drawing, 24.0, [RenderTile(tile=0, rect=drawing.rect)])
    assert alone_ms == 24.0 and alone.readback_ms == 3.0 and np.array_equal(alone.pixels, drawing.pixels)


def test_the_coordinator_sends_pulls_and_times_a_tiles_pieces_together():
    cut, parts = WALL.pieces(Partition(tuple(Tile(t.rect, None) for t in STRIPS.tiles), pull=True))
    job = FrameJob.create(9, Camera.from_json(CAMERA), WALL.size, Codec.PNG, 80, cut, 0.0, parts=parts)
    render = job.render_message(list(range(len(job.tiles))))
    assert [t.part_of for t in render.tiles] == list(parts)
    pulled = [job.pull_next() for _ in range(3)]
    assert [[job.tiles[i].part_of for i in ids] for ids in pulled] == [[t.rect] * len(ids) for t, ids in
                                                                        zip(STRIPS.tiles, pulled, strict=True)]
    assert sum(map(len, pulled)) == len(job.tiles) and not job.pull_queue
    first = job.tiles[pulled[1][0]]
    header = TileHeader(9, first.tile_id, first.rect, Codec.PNG, 4.0, 1.0, 2.0)
    assert job.busy_ms(first.tile_id, header) == pytest.approx(5.0 * first.drawn.area / first.rect.area + 2.0), \
        "the node drew the whole strip before it sent the first piece"


async def node_sends_pieces(renders: list[dict]) -> list[list[tuple[TileHeader, np.ndarray, dict]]]:
    """A real node on a fake coordinator: loads the spheres, answers each of ``renders`` (tiles
    with their part_of): per render, each tile's header, pixels and ``tile_sent`` counters."""
    coordinator = FakeCoordinator()
    async with serve(coordinator.handler, "127.0.0.1", 0) as server:
        port = server.sockets[0].getsockname()[1]
        stop = asyncio.Event()
        node = asyncio.create_task(NodeClient(NodeSettings(coordinator=f"ws://127.0.0.1:{port}/ws/node",
                                                           name="wall")).run(stop))
        try:
            ws = await coordinator.accept()
            await receive_json(ws)
            await send(ws, type="welcome", node_id=1)
            await send(ws, type="load_scene", scene="builtin:spheres", background=list(BACKGROUND))
            while (await receive_json(ws))["type"] != "scene_ready":
                pass
            answers = []
            for render in renders:
                await send(ws, **render)
                tiles = []
                for _ in render["tiles"]:
                    header, payload = unpack_tile(await receive(ws))
                    tile_sent = await receive_json(ws)
                    assert (tile_sent["frame"], tile_sent["tile"]) == (header.frame_id, header.tile_id)
                    tiles.append((header, decode(bytes(payload), header.codec, header.rect.w, header.rect.h),
                                  tile_sent["stats"]))
                answers.append(tiles)
        finally:
            stop.set()
            await asyncio.wait_for(node, seconds(30))
    return answers


@pytest.mark.gl
def test_a_real_nodes_pieces_are_its_frame_and_its_counters_count_one_drawing(ctx):
    size = WALL.size
    base = {"type": "render", "camera": CAMERA, "size": list(size), "codec": "png"}
    pieces = [{"tile": i, "rect": rect, "part_of": part or rect} for i, (rect, part) in enumerate(PIECES[:5])]
    old_form = [{"tile": i, "rect": rect} for i, (rect, _) in enumerate(PIECES[:5])]
    grouped, alone = asyncio.run(node_sends_pieces([{**base, "frame": 1, "tiles": pieces},
                                                    {**base, "frame": 2, "tiles": old_form}]))
    renderer = TileRenderer(ctx, load_scene("builtin:spheres"), BACKGROUND)
    reference = renderer.render_tile(Camera.from_json(CAMERA), size, Rect(0, 0, *size)).pixels
    renderer.release()
    for tiles in (grouped, alone):
        assert [h.tile_id for h, _, _ in tiles] == list(range(5)), "in order, each piece a tile"
        for header, pixels, _ in tiles:
            r = header.rect
            assert np.array_equal(pixels, reference[r.y:r.y1, r.x:r.x1]), f"piece {header.tile_id}"
    drawn = [stats["chunks_drawn"] + stats["chunks_culled"] for _, _, stats in grouped]
    assert drawn[0] > 0 and drawn[1:] == [0] * 4, "one drawing's counters, on its first piece"
    assert all(stats["chunks_drawn"] + stats["chunks_culled"] == drawn[0] for _, _, stats in alone), \
        "the old form: each piece drawn on its own"
    shares = [h.render_ms / h.rect.area for h, _, _ in grouped]
    assert max(shares) == pytest.approx(min(shares)), "one drawing's time shared out by area"


def test_the_pieces_of_one_failed_drawing_are_one_failure_in_a_row():
    s = scheduler(nodes=2, max_tile_failures=2, still_codec=None)
    s.sessions[DEFAULT_SESSION].wall = WallLayout(1, 2, (64, 16))   # each node's 32×32 strip: two pieces
    s.set_camera(camera(0), 0.0)
    assert renders(s.drain()) == {1: [(1, 0), (1, 1)], 2: [(1, 2), (1, 3)]}
    assert [t.part_of for t in s.in_flight[1].tiles] == [Rect(0, 0, 32, 32)] * 2 + [Rect(32, 0, 32, 32)] * 2
    s.tile_failed(2, 1, 2, 0.01)
    s.tile_failed(2, 1, 3, 0.01)
    assert 2 in s.nodes and s.nodes[2].failures == 1, "one drawing failed"
    finish(s, 1, 0.02)
    s.set_camera(camera(1), 0.03)
    s.drain()
    s.tile_failed(2, 2, 2, 0.04)
    assert CloseNode(2, 1011, "2 tiles failed in a row") in s.drain(), "the next drawing's failure is the second"
