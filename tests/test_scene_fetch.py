"""Scene files a node cannot open, fetched by digest (node/scene/fetch.py, issue 19), against a real
HTTP server on port 0 serving a scan from ../shared/scenes: the token as a bearer header to the
coordinator's origin only, downloads cached and reused, a wrong digest or a missing token refused
with the reason."""

from __future__ import annotations

import hashlib
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest

from node.scene.fetch import SceneFetcher, http_origin, resolve_url
from node.scene.loading import load_scene
from node.scene.mesh import SceneError
from tests.conftest import scene_path

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
