"""The coordinator's WebSockets against other sites' pages and greedy peers, in process
(``TestClient``): the Origin check (cross-origin refused with 403 before the handshake, same origin,
the allow-list, behind a TLS proxy, no Origin for nodes), and the limits (viewers, message size,
message rate) closing with a reason that names the flag. A real browser on another origin is in
test_browser_origin.py."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator

import pytest
from fastapi.testclient import TestClient
from starlette.testclient import WebSocketDenialResponse

from server.app import create_app
from tessera.wire.codec import Codec
from tests.conftest import seconds
from tests.test_api import HELLO, SETTINGS, FakeNode, closed_with, next_json

pytestmark = pytest.mark.timeout(seconds(120))

SAME = {"origin": "http://testserver"}  # TestClient's requests go to http://testserver
EVIL = {"origin": "http://evil.example"}


def make_client(**changes) -> TestClient:
    return TestClient(create_app(dataclasses.replace(SETTINGS, **changes)))


@pytest.fixture
def client() -> Iterator[TestClient]:
    with make_client() as client:
        yield client


def refused_before_handshake(client: TestClient, path: str, headers: dict[str, str]) -> WebSocketDenialResponse:
    with pytest.raises(WebSocketDenialResponse) as refused, client.websocket_connect(path, headers=headers):
        pass
    return refused.value


# ------------------------------------------------------------------------------------------- origin


@pytest.mark.parametrize("path", ["/ws/view", "/ws/node"])
@pytest.mark.parametrize("origin", ["http://evil.example", "http://testserver:8080", "https://testserver", "null"])
def test_cross_origin_sockets_are_refused_before_the_handshake(client, path, origin, caplog):
    refused = refused_before_handshake(client, path, {"origin": origin})
    assert refused.status_code == 403
    assert "--allowed-origins" in refused.text and origin in refused.text
    assert any("refused" in r.getMessage() and origin in r.getMessage() for r in caplog.records), "one log line"
    assert client.get("/api/stats").json()["viewers"] == 0


def test_same_origin_viewer_is_accepted(client):
    with client.websocket_connect("/ws/view", headers=SAME) as ws:
        assert ws.receive_json()["type"] == "hello"


def test_no_origin_is_accepted_for_nodes_and_tools(client):
    with client.websocket_connect("/ws/node") as ws:
        FakeNode(ws)
        assert client.get("/api/stats").json()["nodes"]
    with client.websocket_connect("/ws/view") as ws:
        assert ws.receive_json()["type"] == "hello"


@pytest.mark.parametrize(("method", "path", "body"), [
    ("PUT", "/api/camera", {"eye": [3.0, 1.0, 3.0], "target": [0, 0, 0], "up": [0, 1, 0]}),
    ("PUT", "/api/balancer", {"name": "static"}),
    ("POST", "/api/nodes/calibrate", None),
])
def test_writes_from_pages_elsewhere_are_refused_and_change_nothing(client, method, path, body, caplog):
    def state(headers: dict[str, str]) -> tuple:
        camera = client.get("/api/camera", headers=headers).json()
        return camera, client.get("/api/stats", headers=headers).json()["balancer"]

    before = state({})
    refused = client.request(method, path, json=body, headers=EVIL)
    assert refused.status_code == 403, refused.text
    assert "--allowed-origins" in refused.json()["detail"]
    assert any(path in r.getMessage() and "refused" in r.getMessage() for r in caplog.records), "one log line"
    assert state(EVIL) == before, "nothing changed (and reading is not refused: CORS decides what a page reads)"
    for headers in (SAME, {}):
        assert client.request(method, path, json=body, headers=headers).status_code < 400, (method, path, headers)


def test_allow_listed_origins_are_accepted_and_others_not():
    with make_client(allowed_origins=("http://localhost:5173",)) as client:
        with client.websocket_connect("/ws/view", headers={"origin": "http://localhost:5173"}) as ws:
            assert ws.receive_json()["type"] == "hello"
        with client.websocket_connect("/ws/view", headers=SAME) as ws:
            assert ws.receive_json()["type"] == "hello", "same origin still"
        assert refused_before_handshake(client, "/ws/view", EVIL).status_code == 403
    with make_client(allowed_origins=("*",)) as client, client.websocket_connect("/ws/view", headers=EVIL) as ws:
        assert ws.receive_json()["type"] == "hello"


def test_behind_the_tls_proxy(client):
    """nginx (docker/proxy/nginx.conf) forwards Host as the browser sent it and sets
    X-Forwarded-Proto https: the page at https://HOST:8443 is the coordinator's own."""
    proxied = {"host": "tessera.example:8443", "x-forwarded-proto": "https"}
    with client.websocket_connect("/ws/view", headers={**proxied, "origin": "https://tessera.example:8443"}) as ws:
        assert ws.receive_json()["type"] == "hello"
    assert refused_before_handshake(client, "/ws/view", {**proxied, "origin": "http://tessera.example:8443"})
    assert refused_before_handshake(client, "/ws/view", {"host": "tessera.example:8443",
                                                         "origin": "https://tessera.example:8443"}), \
        "a TLS proxy that sets no X-Forwarded-Proto needs --allowed-origins"
    assert refused_before_handshake(client, "/ws/view", {**proxied, "origin": "https://evil.example"})


def test_origin_is_checked_before_the_token():
    with make_client(token="s3cret") as client:
        refused = refused_before_handshake(client, "/ws/view?token=s3cret", EVIL)
        assert refused.status_code == 403
        with client.websocket_connect("/ws/view?token=s3cret", headers=SAME) as ws:
            assert ws.receive_json()["type"] == "hello"


# ------------------------------------------------------------------------------------------- limits


def test_viewer_over_max_viewers_is_refused_with_the_reason(caplog):
    with make_client(max_viewers=2) as client:
        with client.websocket_connect("/ws/view") as first, client.websocket_connect("/ws/view") as second:
            assert first.receive_json()["type"] == second.receive_json()["type"] == "hello"
            with client.websocket_connect("/ws/view") as third:
                code, reason = closed_with(third)
            assert code == 1008 and "too many viewers: 2 of 2" in reason and "--max-viewers" in reason
            assert any("--max-viewers" in r.getMessage() for r in caplog.records)
            assert client.get("/api/stats").json()["viewers"] == 2
        with client.websocket_connect("/ws/view") as again:
            assert again.receive_json()["type"] == "hello", "room again once viewers left"


def test_oversized_viewer_message_is_closed_with_the_reason():
    with make_client(max_viewer_message_bytes=1000) as client, client.websocket_connect("/ws/view") as ws:
        assert ws.receive_json()["type"] == "hello"
        ws.send_text('{"type": "latency", "pad": "' + "x" * 500 + '", "p50_ms": 1, "p90_ms": 1, "samples": 1, '
                     '"interval_ms": 16}')
        ws.send_text("x" * 1001)
        code, reason = closed_with(ws)
        assert code == 1009 and "1001 bytes" in reason and "--max-viewer-message-bytes" in reason


def test_oversized_node_tile_is_closed_with_the_reason():
    with make_client(max_node_message_bytes=4096) as client, client.websocket_connect("/ws/node") as ws:
        FakeNode(ws)
        ws.send_bytes(b"\0" * 4097)
        code, reason = closed_with(ws)
        assert code == 1009 and "--max-node-message-bytes" in reason
        assert client.get("/api/stats").json()["nodes"] == []


def test_default_node_limit_carries_a_raw_frame():
    """--codec raw: the whole frame as one tile is far under the default limit (one node)."""
    with make_client(codec=Codec.RAW, size=(256, 192)) as client, \
            client.websocket_connect("/ws/node") as ws:
        node = FakeNode(ws)
        node.answer_until(1)
        assert node.tiles_sent >= 1 and client.get("/api/stats").json()["nodes"]


def test_viewer_flood_is_closed_with_the_reason(caplog):
    with make_client(max_viewer_messages_per_s=20) as client, client.websocket_connect("/ws/view") as ws:
        assert ws.receive_json()["type"] == "hello"
        for _ in range(200):
            ws.send_json({"type": "latency", "p50_ms": 1, "p90_ms": 2, "samples": 3, "interval_ms": 16})
        code, reason = closed_with(ws)
        assert code == 1008 and "20 messages/s" in reason and "--max-viewer-messages-per-s" in reason
    assert any("--max-viewer-messages-per-s" in r.getMessage() for r in caplog.records)


def test_node_flood_is_closed_with_the_reason():
    with make_client(max_node_messages_per_s=50) as client, client.websocket_connect("/ws/node") as ws:
        FakeNode(ws)
        for _ in range(500):
            ws.send_json({"type": "scene_progress", "scene": "x", "fraction": 0.5, "message": "flood"})
        code, reason = closed_with(ws)
        assert code == 1008 and "--max-node-messages-per-s" in reason


def test_the_hello_counts_too():
    """The limits hold from the first message: an oversized hello is closed like any message."""
    with make_client(max_node_message_bytes=2048) as client, client.websocket_connect("/ws/node") as ws:
        ws.send_json({**HELLO, "name": "x" * 4096})
        assert closed_with(ws)[0] == 1009


def test_a_viewer_within_the_limits_keeps_going(client):
    with client.websocket_connect("/ws/view", headers=SAME) as ws:
        next_json(ws, "hello")
        for seq in range(50):
            ws.send_json({"type": "camera", "seq": seq,
                          "camera": {"eye": [0, 0, 4], "target": [0, 0, 0], "up": [0, 1, 0]}})
        ws.send_json({"type": "nope"})
        assert next_json(ws, "error")["message"], "still open: it answers"
