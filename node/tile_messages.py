"""The binary tile messages a render node sends (:mod:`tessera.wire.protocol`): a drawn tile (or a
piece of one, :func:`cut_pieces`), or a depth tile (:mod:`tessera.wire.depth_tiles`), encoded with
its phase times in the header. They run in the node's encoder thread, apart from drawing and
sending (seed 002 §4)."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from typing import Any

from node.gl.renderer import RenderedTile
from tessera.compositing.layers import BlendLayer, DepthLayer
from tessera.geometry import Rect
from tessera.scene.state import SceneState
from tessera.wire.codec import Codec, encode
from tessera.wire.depth_tiles import encode_depth_tile
from tessera.wire.messages import RenderTile
from tessera.wire.protocol import TileHeader, pack_tile, state_tag


def encode_tile(frame: int, tile: RenderTile, rendered: RenderedTile, render_ms: float,
                codec: Codec, jpeg_quality: int, state: SceneState | None = None) -> bytes:
    """The binary tile message: header with the phase times and the ``state`` drawn + the encoded pixels."""
    started = time.perf_counter()
    payload = encode(rendered.pixels, codec, jpeg_quality)
    encode_ms = (time.perf_counter() - started) * 1e3
    header = TileHeader(frame, tile.tile, tile.rect, codec, render_ms, rendered.readback_ms, encode_ms,
                        state_tag(None if state is None else state.version))
    return pack_tile(header, payload)


def cut_pieces(rendered: RenderedTile, render_ms: float,
               pieces: Sequence[RenderTile]) -> list[tuple[RenderedTile, float]]:
    """The ``pieces`` (rects inside ``rendered.rect``, a display wall's cut of one tile) of one
    drawing, each as a tile of its own with its render time (ms): its pixels a view of the drawing's,
    the drawing's render (``render_ms``, slowdown included) and read-back times shared out in
    proportion to area (so the balancer, which reads the pieces' timings, sees the drawing's cost
    spread over its pixels), its counters on the first piece (the others draw nothing more)."""
    whole = rendered.rect
    out = []
    for index, piece in enumerate(pieces):
        r, share = piece.rect, piece.rect.area / whole.area
        pixels = rendered.pixels[r.y - whole.y:r.y1 - whole.y, r.x - whole.x:r.x1 - whole.x]
        counted = rendered if index == 0 else dataclasses.replace(rendered, triangles=0, chunks_drawn=0,
                                                                   chunks_culled=0, cull_ms=0.0)
        out.append((dataclasses.replace(counted, rect=r, pixels=pixels, readback_ms=rendered.readback_ms * share),
                    render_ms * share))
    return out


def encode_depth_message(frame: int, tile: RenderTile, layer: DepthLayer | None, core: Rect | None,
                         blend: BlendLayer | None, times: tuple[float, float], codec: Codec, jpeg_quality: int,
                         state: SceneState | None, version: int, stats: dict[str, Any]) -> bytes:
    """The binary depth tile message of ``layer`` (None: nothing in view) with its ``core`` as an
    image in ``codec`` and its ``blend`` layer, drawn and read back in ``times`` (ms); the tile's
    byte counts are added to ``stats`` (its ``tile_sent`` counters)."""
    started = time.perf_counter()
    payload, counts = encode_depth_tile(layer, core, codec, jpeg_quality, version, blend)
    encode_ms = (time.perf_counter() - started) * 1e3
    stats.update(counts.as_stats())
    header = TileHeader(frame, tile.tile, tile.rect, codec, *times, encode_ms,
                        state_tag(None if state is None else state.version), depth=True)
    return pack_tile(header, payload)
