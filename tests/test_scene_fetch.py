"""Scene files a node cannot open, fetched by digest (node/scene/fetch.py, issue 19), against a real
HTTP server on port 0 serving a scan from ../shared/scenes: the token as a bearer header to the
coordinator's origin only, downloads cached and reused, a wrong digest or a missing token refused
with the reason; and a node (NodeClient) loading a scene file its coordinator serves."""

from __future__ import annotations

import asyncio
import hashlib
import json
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest
from websockets.asyncio.server import ServerConnection, serve
from websockets.datastructures import Headers
from websockets.http11 import Request, Response

from node.client import NodeClient
from node.scene.cache import CACHE_FORMAT
from node.scene.fetch import SceneFetcher, http_origin, resolve_url
from node.scene.loading import load_scene
from node.scene.mesh import SceneError
from node.scene.octree import DEFAULT_FACE_LIMIT
from node.settings import NodeSettings
from tessera.wire.protocol import unpack_tile
from tests.conftest import scene_path, seconds
from tests.test_node_client import FakeCoordinator, receive, receive_json, send

BUNNY = "bunny/bun_zipper.ply"
BUNNY_TRIANGLES = 69_451
FILE_PATH = "/api/scenes/bunny/file"
TOKEN = "s3cret"
#: The scene's name on the coordinator: a path no node here can open.
SPEC = "/no/such/folder/bun_zipper.ply"
WRONG = "0" * 64


def no_progress(fraction: float, message: str) -> None:
    pass


@dataclass
class ScanServer:
    """An HTTP server on port 0 serving ``data`` at :data:`FILE_PATH` to requests that carry the
    token; ``requests``: (path, Authorization header) of each request."""

    data: bytes
    port: int = 0
    requests: list[tuple[str, str | None]] = field(default_factory=list)

    @property
    def coordinator(self) -> str:
        return f"ws://127.0.0.1:{self.port}/ws/node"

    @property
    def digest(self) -> str:
        return hashlib.sha256(self.data).hexdigest()


@pytest.fixture(scope="module")
def bunny_bytes() -> bytes:
    return scene_path(BUNNY).read_bytes()


@pytest.fixture
def scan_server(bunny_bytes: bytes) -> Iterator[ScanServer]:
    served = ScanServer(bunny_bytes)

    class Handler(BaseHTTPRequestHandler):
        def do_GET(self) -> None:
            authorization = self.headers.get("Authorization")
            served.requests.append((self.path, authorization))
            if self.path != FILE_PATH:
                self.send_error(404)
            elif authorization != f"Bearer {TOKEN}":
                self.send_error(401, "Unauthorized")
            else:
                self.send_response(200)
                self.send_header("Content-Length", str(len(served.data)))
                self.end_headers()
                self.wfile.write(served.data)

        def log_message(self, format: str, *args: object) -> None:
            pass

    server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    served.port = server.server_address[1]
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield served
    finally:
        server.shutdown()
        server.server_close()
        thread.join()


def test_urls_are_resolved_against_the_coordinator():
    assert http_origin("ws://render-hub:8000/ws/node") == "http://render-hub:8000"
    assert http_origin("wss://render.example.org/ws/node") == "https://render.example.org"
    assert resolve_url("/api/scenes/x/file", "http://render-hub:8000") == "http://render-hub:8000/api/scenes/x/file"
    assert resolve_url("https://cdn.example.org/x.ply", "http://render-hub:8000") == "https://cdn.example.org/x.ply"


def test_a_scene_the_node_cannot_open_is_downloaded_once_into_the_cache(scan_server, tmp_path):
    cache = tmp_path / "cache"
    fetcher = SceneFetcher(scan_server.coordinator, TOKEN, cache)
    progress: list[str] = []
    path = fetcher.source(SPEC, scan_server.digest, FILE_PATH, lambda fraction, message: progress.append(message))
    assert path == str(cache / f"{scan_server.digest}.ply")
    assert (cache / f"{scan_server.digest}.ply").read_bytes() == scan_server.data
    assert [p.name for p in cache.iterdir()] == [f"{scan_server.digest}.ply"], "no partial file is left"
    assert scan_server.requests == [(FILE_PATH, f"Bearer {TOKEN}")], "the token as a bearer header, not in the query"
    assert progress[0].startswith("downloading bun_zipper.ply") and progress[-1].startswith("downloaded")
    assert fetcher.source(SPEC, scan_server.digest, FILE_PATH, no_progress) == path
    assert len(scan_server.requests) == 1, "a cached file is reused without a download"
    assert load_scene(path).triangle_count == BUNNY_TRIANGLES


def test_a_file_the_node_can_open_is_never_fetched(scan_server, tmp_path):
    fetcher = SceneFetcher(scan_server.coordinator, TOKEN, tmp_path)
    local = str(scene_path(BUNNY))
    digest = scan_server.digest
    for spec, sha256, url in [(local, digest, FILE_PATH), ("builtin:spheres", digest, FILE_PATH), (SPEC, None, None),
                              ("/no/such/scene.xyz", digest, FILE_PATH)]:
        assert fetcher.source(spec, sha256, url, no_progress) == spec
    assert scan_server.requests == [] and not any(tmp_path.iterdir())


def test_bytes_of_another_digest_are_refused_and_removed(scan_server, tmp_path):
    fetcher = SceneFetcher(scan_server.coordinator, TOKEN, tmp_path)
    with pytest.raises(SceneError) as caught:
        fetcher.source(SPEC, WRONG, FILE_PATH, no_progress)
    message = str(caught.value)
    assert message.startswith(f"{SPEC}: the {len(scan_server.data)} bytes downloaded from http://127.0.0.1:")
    assert f"have sha256 {scan_server.digest}, not {WRONG}" in message
    assert not any(tmp_path.iterdir()), "neither a cached file nor a partial one"


def test_a_download_without_the_token_is_refused_with_the_status(scan_server, tmp_path):
    for token in (None, "wrong"):
        with pytest.raises(SceneError, match=f"{SPEC}: download from .* failed: HTTP 401 Unauthorized$"):
            SceneFetcher(scan_server.coordinator, token, tmp_path).source(SPEC, scan_server.digest, FILE_PATH,
                                                                          no_progress)
    elsewhere = f"http://localhost:{scan_server.port}{FILE_PATH}"   # another origin than 127.0.0.1
    with pytest.raises(SceneError, match=r"HTTP 401 Unauthorized \(the token goes to the coordinator's origin only"):
        SceneFetcher(scan_server.coordinator, TOKEN, tmp_path).source(SPEC, scan_server.digest, elsewhere, no_progress)
    assert [authorization for _, authorization in scan_server.requests] == [None, "Bearer wrong", None]
    assert not any(tmp_path.iterdir())


def test_an_unreachable_server_is_a_scene_error(scan_server, tmp_path):
    fetcher = SceneFetcher("ws://127.0.0.1:9/ws/node", TOKEN, tmp_path)
    with pytest.raises(SceneError, match=r"download from http://127\.0\.0\.1:9/api/scenes/bunny/file into .* failed"):
        fetcher.source(SPEC, scan_server.digest, FILE_PATH, no_progress)


async def serve_bunny_file(data: bytes, connection: ServerConnection, request: Request) -> Response | None:
    """The fake coordinator's HTTP side: the scene file to requests with the token, the WebSocket otherwise."""
    if request.path != FILE_PATH:
        return None
    if request.headers.get("Authorization") != f"Bearer {TOKEN}":
        return connection.respond(401, "no token\n")
    return Response(200, "OK", Headers({"Content-Length": str(len(data)), "Content-Type": "application/octet-stream"}),
                    data)


async def node_fetches_from_its_coordinator(data: bytes, cache) -> tuple[dict, bytes, dict]:
    """A node with a token loads a scene file its coordinator serves and renders a tile of it, then
    is asked for the file with a wrong digest; returns (scene_ready, the tile, scene_error)."""
    coordinator = FakeCoordinator()
    digest = hashlib.sha256(data).hexdigest()
    async with serve(coordinator.handler, "127.0.0.1", 0,
                     process_request=lambda connection, request: serve_bunny_file(data, connection, request)) as server:
        port = server.sockets[0].getsockname()[1]
        settings = NodeSettings(coordinator=f"ws://127.0.0.1:{port}/ws/node", name="fetcher", token=TOKEN,
                                scene_cache_dir=cache)
        stop = asyncio.Event()
        node = asyncio.create_task(NodeClient(settings).run(stop))
        try:
            ws = await coordinator.accept()
            assert (await receive_json(ws))["type"] == "hello"
            await send(ws, type="welcome", node_id=1)
            await send(ws, type="load_scene", scene=SPEC, sha256=digest, url=FILE_PATH)
            while (ready := await receive_json(ws))["type"] == "scene_progress":
                pass
            camera = {"eye": [0.0, 0.1, 0.3], "target": [-0.02, 0.1, 0.0]}
            await send(ws, type="render", frame=1, camera=camera, size=[64, 48], codec="png", scene=SPEC,
                       tiles=[{"tile": 0, "rect": [0, 0, 64, 48]}])
            tile = await receive(ws)
            assert (await receive_json(ws))["type"] == "tile_sent"
            await send(ws, type="load_scene", scene="/elsewhere/bun_zipper.ply", sha256=WRONG, url=FILE_PATH)
            while (error := await receive_json(ws))["type"] == "scene_progress":
                pass
        finally:
            stop.set()
            await asyncio.wait_for(node, seconds(30))
    assert isinstance(tile, bytes)
    return ready, tile, error


@pytest.mark.gl
def test_a_node_loads_a_scene_file_its_coordinator_serves(bunny_bytes, tmp_path):
    ready, tile, error = asyncio.run(node_fetches_from_its_coordinator(bunny_bytes, tmp_path))
    assert ready["type"] == "scene_ready", json.dumps(ready)
    assert ready["scene"] == SPEC and ready["triangles"] == BUNNY_TRIANGLES
    header, _ = unpack_tile(tile)
    assert (header.frame_id, header.tile_id) == (1, 0)
    assert error["type"] == "scene_error" and error["scene"] == "/elsewhere/bun_zipper.ply"
    assert f"not {WRONG}" in error["message"]
    digest = hashlib.sha256(bunny_bytes).hexdigest()
    files = sorted(p.name for p in tmp_path.iterdir() if p.is_file())
    assert files == [f"{digest}-f{DEFAULT_FACE_LIMIT}-v{CACHE_FORMAT}.lock", f"{digest}.ply"], \
        "the fetched file (and the lock of the cache entry built from it), nothing of the wrong download"
    assert [p.name for p in tmp_path.iterdir() if p.is_dir() and not p.name.startswith(".")] == \
        [f"{digest}-f{DEFAULT_FACE_LIMIT}-v{CACHE_FORMAT}"], "the scene cache entry, beside the file"
