"""What a coordinator exposed on a shared network answers (in process, ``TestClient``): the token
from a cookie the viewer page sets, ``/metrics`` and ``/healthz`` open, and error answers that stay
valid JSON whatever the client sent (NaN, infinity, huge or non-ASCII input)."""

from __future__ import annotations

import json

import pytest
from fastapi.testclient import TestClient

from server.app import create_app
from server.routes.deps import TOKEN_COOKIE
from server.settings import Settings

TOKEN = "s3cret"


@pytest.fixture
def client():
    with TestClient(create_app(Settings(scene="builtin:spheres", size=(64, 48), token=TOKEN))) as client:
        yield client


def test_the_viewer_page_sets_the_token_cookie_only_for_the_right_token(client):
    page = client.get("/", params={"token": TOKEN})
    assert page.status_code == 200 and "web/viewer.js" in page.text
    cookie = page.headers["set-cookie"]
    assert cookie.startswith(f"{TOKEN_COOKIE}={TOKEN};")
    assert "HttpOnly" in cookie and "SameSite=strict" in cookie and "Path=/" in cookie
    assert "set-cookie" not in client.get("/", params={"token": "wrong"}).headers
    assert "set-cookie" not in client.get("/").headers, "no token, no cookie: the page itself is open"


def test_the_cookie_opens_the_api_and_the_viewer_socket(client):
    assert client.get("/api/stats").status_code == 401
    client.cookies.set(TOKEN_COOKIE, TOKEN)
    assert client.get("/api/stats").status_code == 200
    with client.websocket_connect("/ws/view") as ws:
        assert ws.receive_json()["type"] == "hello"
    client.cookies.set(TOKEN_COOKIE, "wrong")
    assert client.get("/api/stats").status_code == 401


def test_metrics_and_health_stay_open(client):
    assert client.get("/healthz").status_code == 200
    metrics = client.get("/metrics")
    assert metrics.status_code == 200 and "tessera_frame_id" in metrics.text


@pytest.mark.parametrize("token", ["é-not-ascii", "\u0000", "x" * 10_000, ""])
def test_any_token_text_is_refused_cleanly(client, token):
    assert client.get("/api/stats", headers={"X-Tessera-Token": token.encode()}).status_code == 401
    assert client.get("/api/stats", params={"token": token}).status_code == 401


@pytest.mark.parametrize("body", [
    '{"eye": [NaN, "x", 1], "target": [0, 0, 0]}', '{"name": NaN}', '[NaN]', '{"eye": [Infinity, 0, 1]}',
    '{"name": "static", "params": {"min_tile_px": NaN}}', json.dumps({"name": "x" * 100_000}),
    json.dumps({"eye": [[[[[[[[[[[1]]]]]]]]]]], "target": [0, 0, 0]}),
])
@pytest.mark.parametrize("path", ["/api/camera", "/api/balancer"])
def test_refusals_echoing_bad_input_stay_valid_json(client, path, body):
    response = client.put(path, content=body, headers={"content-type": "application/json",
                                                       "Authorization": f"Bearer {TOKEN}"})
    assert response.status_code == 422, response.text[:300]
    detail = response.json()["detail"]
    assert detail and len(response.content) < 20_000, "the echo is cut short"
