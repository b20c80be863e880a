"""Cross-site WebSocket hijacking, in a real browser: a page served from another origin (another port
on the same machine) cannot open the viewer socket of a running coordinator; the coordinator's own
page can. Debian's headless Chromium through Playwright (see browser_support.py)."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest

from tests.browser_support import chromium_context
from tests.conftest import seconds

pytestmark = pytest.mark.browser

# Opens a WebSocket to the URL given and says how it went: the first message's type, or that it failed.
OPEN_SOCKET_JS = """(url) => new Promise((resolve) => {
  const socket = new WebSocket(url);
  socket.onmessage = (event) => { resolve("message " + JSON.parse(event.data).type); socket.close(); };
  socket.onerror = () => resolve("error");
  socket.onclose = (event) => resolve("closed " + event.code);
})"""


class _Page(BaseHTTPRequestHandler):
    def do_GET(self) -> None:
        body = b"<!doctype html><title>another site</title><p>not the coordinator</p>"
        self.send_response(200)
        self.send_header("Content-Type", "text/html")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, *args) -> None:
        pass


@pytest.fixture
def other_site() -> Iterator[str]:
    """A web server on another port of this machine: another origin."""
    server = ThreadingHTTPServer(("127.0.0.1", 0), _Page)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{server.server_address[1]}"
    server.shutdown()
    server.server_close()


def test_a_page_of_another_origin_cannot_open_the_viewer_socket(coordinator_factory, other_site, tmp_path):
    coordinator = coordinator_factory("--scene", "builtin:spheres", "--size", "64x48")
    socket_url = coordinator.ws_url + "/ws/view"
    with chromium_context(tmp_path / "chromium-profile") as context:
        page = context.new_page()
        page.set_default_timeout(seconds(30) * 1000)
        page.goto(other_site + "/")
        assert page.evaluate(OPEN_SOCKET_JS, socket_url) == "error", "cross-origin viewer socket: refused"
        coordinator.proc.wait_for_line(rf"viewer socket from .* refused: origin '{other_site}'", seconds(10))
        page.goto(coordinator.url + "/")
        assert page.evaluate(OPEN_SOCKET_JS, socket_url) == "message hello", "same origin: accepted"
