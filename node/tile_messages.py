"""The binary tile messages a render node sends (:mod:`tessera.wire.protocol`): a drawn tile, or a
depth tile (:mod:`tessera.wire.depth_tiles`), encoded with its phase times in the header. They run
in the node's encoder thread, apart from drawing and sending (seed 002 §4)."""

from __future__ import annotations

import time
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
