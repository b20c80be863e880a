"""Synthetic render nodes, many in one process: they speak the real node protocol
(:mod:`tessera.wire.messages`, :mod:`tessera.wire.protocol`) over ``/ws/node`` but draw nothing, so a
coordinator can be loaded with more nodes than the machine could render for.

``python -m bench.synthetic_nodes --url ws://HOST:PORT/ws/node --nodes K [--max-seconds 600]``

Each node says hello (calibration capable), answers ``load_scene`` with a ``scene_ready`` for the
box [-1, 1]³ (no primitive groups), ``calibrate`` with :data:`CALIBRATION_MS`, and every
``render`` at once, in order: per tile the binary tile (:func:`tessera.wire.protocol.pack_tile`, phase
times :data:`TILE_PHASES_MS`) carrying a pre-encoded image of exactly the tile's size in the
requested codec (:func:`tile_payload`: cut from one fixed noisy gradient, encoded once per
(codec, quality, frame size, w, h) and cached), then its ``tile_sent``. A ``cancel`` drops the
cancelled frames' tiles still queued, reported with ``tiles_dropped``.

Runs until SIGINT/SIGTERM or ``--max-seconds``, then prints one JSON line: per node its name,
tiles sent, tiles dropped and how its connection ended.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import functools
import json
import logging
import signal
import sys
import time
from collections import deque
from typing import Any

import numpy as np
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed

from tessera.wire.codec import Codec, encode
from tessera.wire.messages import (
    TO_NODE,
    Calibrate,
    Calibration,
    Cancel,
    Capabilities,
    LoadScene,
    NodeHello,
    Render,
    SceneReady,
    TilesDropped,
    TileSent,
    parse,
)
from tessera.wire.protocol import PROTOCOL_VERSION, TileHeader, pack_tile

log = logging.getLogger("tessera.synthetic")

#: render, read-back and encode ms written into every tile header
TILE_PHASES_MS = (1.0, 0.2, 0.3)
#: every node's answer to ``calibrate`` (equal speeds)
CALIBRATION_MS = 5.0
SCENE_BOUNDS = ((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0))
#: ± levels of seeded uniform noise on the gradient: JPEG q60 of a 1920x1080 frame of it is ~52 KB,
#: about what a rendered frame of Lucy takes (54 KB)
NOISE_LEVELS = 6
#: cancelled frame ids a node remembers (as ``node.client``)
CANCELLED_MEMORY = 256
MAX_MESSAGE_BYTES = 64 << 20


@functools.lru_cache(maxsize=4)
def gradient_image(width: int, height: int) -> np.ndarray:
    """(height, width, 3) uint8: a diagonal colour gradient with seeded ±:data:`NOISE_LEVELS` noise."""
    y, x = np.mgrid[0:height, 0:width].astype(np.float32)
    base = np.stack([255.0 * x / width, 255.0 * y / height, 127.5 * (x / width + y / height)], axis=-1)
    noise = np.random.default_rng(0).integers(-NOISE_LEVELS, NOISE_LEVELS + 1, size=base.shape)
    return np.clip(base + noise, 0, 255).astype(np.uint8)


@functools.lru_cache(maxsize=4096)
def tile_payload(codec: Codec, quality: int, frame_size: tuple[int, int], width: int, height: int) -> bytes:
    """The encoded top-left ``width`` × ``height`` of the frame-sized gradient."""
    pixels = np.ascontiguousarray(gradient_image(*frame_size)[:height, :width])
    return encode(pixels, codec, quality)


class SyntheticNode:
    """One node: :meth:`run` serves a connection until ``stop`` is set or the coordinator closes it."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.tiles_sent = 0
        self.tiles_dropped = 0
        self.ended = "not connected"
        self._cancelled: deque[int] = deque(maxlen=CANCELLED_MEMORY)

    def hello(self) -> NodeHello:
        return NodeHello(name=self.name, renderer="synthetic (pre-encoded tiles, no GL)", version=PROTOCOL_VERSION,
                         capabilities=Capabilities(calibrate=True))

    async def run(self, url: str, stop: asyncio.Event) -> None:
        try:
            async with connect(url, max_size=MAX_MESSAGE_BYTES, compression=None, proxy=None) as ws:
                await ws.send(self.hello().to_text())
                jobs: asyncio.Queue[LoadScene | Render | Calibrate] = asyncio.Queue()
                tasks = [asyncio.create_task(self._receive(ws, jobs)), asyncio.create_task(self._answer(ws, jobs)),
                         asyncio.create_task(stop.wait())]
                done, _ = await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
                for task in tasks:
                    task.cancel()
                await asyncio.gather(*tasks, return_exceptions=True)
                errors = [t.exception() for t in done if not t.cancelled() and t.exception() is not None]
                for error in errors:
                    if not isinstance(error, ConnectionClosed):
                        log.error("%s failed", self.name, exc_info=error)
                closed = f"closed by the coordinator: {ws.close_code} {ws.close_reason}".strip()
                self.ended = "stopped" if stop.is_set() else closed
        except (OSError, ConnectionClosed) as exc:
            self.ended = f"connection failed: {exc}"

    async def _receive(self, ws: ClientConnection, jobs: asyncio.Queue[LoadScene | Render | Calibrate]) -> None:
        async for raw in ws:
            match parse(raw, TO_NODE):
                case Cancel(frames=frames):
                    self._cancelled.extend(frames)
                case LoadScene() | Render() | Calibrate() as message:
                    jobs.put_nowait(message)

    async def _answer(self, ws: ClientConnection, jobs: asyncio.Queue[LoadScene | Render | Calibrate]) -> None:
        while True:
            match await jobs.get():
                case LoadScene():
                    await ws.send(SceneReady(triangles=1000, bounds=SCENE_BOUNDS).to_text())
                case Calibrate():
                    await ws.send(Calibration(ms=CALIBRATION_MS).to_text())
                case Render() as message:
                    await self._render(ws, message)

    async def _render(self, ws: ClientConnection, message: Render) -> None:
        frame, codec = message.frame, message.codec
        dropped = []
        for entry in message.tiles:
            if frame in self._cancelled:
                dropped.append(entry.tile)
                continue
            rect = entry.rect
            header = TileHeader(frame, entry.tile, rect, codec, *TILE_PHASES_MS)
            started = time.perf_counter()
            await ws.send(pack_tile(header, tile_payload(codec, message.jpeg_quality, message.size, rect.w, rect.h)))
            send_ms = (time.perf_counter() - started) * 1e3
            await ws.send(TileSent(frame=frame, tile=entry.tile, send_ms=send_ms).to_text())
            self.tiles_sent += 1
        if dropped:
            self.tiles_dropped += len(dropped)
            await ws.send(TilesDropped(frame=frame, tiles=tuple(dropped)).to_text())

    def summary(self) -> dict[str, Any]:
        return {"name": self.name, "tiles_sent": self.tiles_sent, "tiles_dropped": self.tiles_dropped,
                "ended": self.ended}


async def serve(url: str, count: int, max_seconds: float) -> list[dict[str, Any]]:
    """Run ``count`` nodes against ``url`` until SIGINT/SIGTERM or ``max_seconds``; their summaries."""
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for signum in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(signum, stop.set)
    nodes = [SyntheticNode(f"synthetic-{i + 1}") for i in range(count)]
    tasks = [asyncio.create_task(node.run(url, stop)) for node in nodes]
    with contextlib.suppress(TimeoutError):
        await asyncio.wait_for(stop.wait(), max_seconds)
    stop.set()
    await asyncio.gather(*tasks)
    return [node.summary() for node in nodes]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.synthetic_nodes", description=__doc__.split("\n\n")[0])
    parser.add_argument("--url", required=True, help="the coordinator's ws://HOST:PORT/ws/node")
    parser.add_argument("--nodes", type=int, default=4)
    parser.add_argument("--max-seconds", type=float, default=600.0, help="exit after this long at the latest")
    args = parser.parse_args(argv)
    logging.basicConfig(level="WARNING", format="%(asctime)s %(name)s %(levelname)s %(message)s")
    summaries = asyncio.run(serve(args.url, args.nodes, args.max_seconds))
    print(json.dumps({"nodes": summaries}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
