"""Helpers shared by the frame scheduler's tests: nodes answering the render messages it sends."""

from __future__ import annotations

from tessera.scheduling.actions import RenderTiles
from tessera.scheduling.scheduler import FrameScheduler
from tessera.wire.protocol import TileHeader, state_tag


def answer(s: FrameScheduler, action: RenderTiles, now: float) -> list:
    """Every tile of ``action`` comes back at ``now`` (drawn in 1 ms, in the codec its frame asked
    for, showing its frame's scene state); the actions that follow."""
    job = s.in_flight[action.message.frame]
    tag = state_tag(None if job.state is None else job.state.version)
    for tile in action.message.tiles:
        header = TileHeader(action.message.frame, tile.tile, tile.rect, job.codec, 1.0, 0.0, 0.0, tag)
        s.tile_arrived(action.node_id, header, b"", now)
        s.tile_sent(action.node_id, action.message.frame, tile.tile, 0.0)
    return s.drain()
