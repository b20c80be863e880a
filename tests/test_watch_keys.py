"""A watch link only watches (issue 38), in process with a fake node: every route of the OpenAPI
schema that may change something refuses a request made with a watch key (in place of the session's
id, or in the ``X-Tessera-Watch`` header the watch page sends) with 403 and the reason, and nothing
changes; the same requests without the watch key reach their routes. A watch key reads its own
session's figures, never an id that drives a session."""

from __future__ import annotations

import re
from collections.abc import Iterator
from typing import Any

import pytest
from fastapi.testclient import TestClient

from server.app import create_app
from server.routes.guards import WATCH_KEYS_CHANGE_NOTHING
from tests.conftest import seconds
from tests.test_api_sessions import SETTINGS, SceneNode

pytestmark = pytest.mark.timeout(seconds(120))

CHANGING = ("post", "put", "patch", "delete")
#: A body each changing route would take (by the end of its path), so that refusing it is the watch
#: key's doing and not a bad request's.
BODIES: dict[str, dict[str, Any]] = {
    "/camera": {"json": {"eye": [0.0, 1.0, 9.0], "target": [0.0, 0.0, 0.0]}},
    "/balancer": {"json": {"name": "static", "params": {}}},
    "/size": {"json": {"size": [40, 30]}},
    "/animation": {"json": {"playing": True}},
    "/objects/{name}": {"json": {"visible": False}},
    "/api/sessions": {"json": {"scene": "builtin:cluster"}},
    "/api/scenes": {"files": {"file": ("box.ply", b"ply\n")}},
}


@pytest.fixture
def client() -> Iterator[TestClient]:
    with TestClient(create_app(SETTINGS)) as client:
        yield client


def watch_key(body: dict[str, Any]) -> str:
    return body["watch_url"].split("session=")[1].split("&")[0]


def changing_routes(client: TestClient) -> list[tuple[str, str]]:
    """(method, path template) of every route the OpenAPI schema lists that may change something."""
    paths = client.get("/openapi.json").json()["paths"]
    return [(method, path) for path, item in paths.items() for method in item if method in CHANGING]


def request_for(path: str, key: str) -> tuple[str, dict[str, Any]]:
    """The URL of ``path`` for session ``key`` (other path parameters: an object name), and its body."""
    body = next((value for end, value in BODIES.items() if path.endswith(end)), {})
    return re.sub(r"\{[^}]*\}", "car", path.replace("{session_id}", key)), body


def state(client: TestClient, session_id: str) -> dict[str, Any]:
    """What a change would show: both sessions' summaries and balancers, the sessions and scenes."""
    def of(prefix: str) -> dict[str, Any]:
        summary = client.get(f"{prefix}/stats").json()
        return {"camera": client.get(f"{prefix}/camera").json()["camera"], "size": summary["size"],
                "balancer": client.get(f"{prefix}/balancer").json()["name"], "scene": summary["scene"],
                "objects": client.get(f"{prefix}/objects").json()}

    return {"session": of(f"/api/sessions/{session_id}"), "default": of("/api"),
            "sessions": sorted(s["id"] for s in client.get("/api/sessions").json()),
            "scenes": client.get("/api/scenes").json(), "calibrations": [
                n["calibration_ms"] for n in client.get("/api/stats").json()["nodes"]]}


def test_every_route_that_changes_something_refuses_a_watch_key_and_nothing_changes(client):
    body = client.post("/api/sessions", json={"scene": "builtin:cluster", "size": [32, 16]}).json()
    key = watch_key(body)
    with client.websocket_connect("/ws/node") as ws:
        node = SceneNode(ws)
        first = client.put(f"/api/sessions/{body['id']}/camera", json={"eye": [0, 0, 5], "target": [0, 0, 0]})
        node.serve(lambda render: render["scene"] == "builtin:cluster" and render["frame"] >= first.json()["frame"])
        routes = changing_routes(client)
        assert len(routes) >= 9, routes
        before = state(client, body["id"])
        for method, path in routes:
            per_session = "{session_id}" in path
            url, payload = request_for(path, key if per_session else "default")
            headers = {} if per_session else {"X-Tessera-Watch": key}
            answer = client.request(method.upper(), url, headers=headers, **payload)
            assert answer.status_code == 403, f"{method.upper()} {url} with a watch key: {answer.status_code}"
            assert answer.json()["detail"] == WATCH_KEYS_CHANGE_NOTHING
        assert state(client, body["id"]) == before, "a refused change changed nothing"

        # The same requests without the watch key reach their routes (the refusal was the key's).
        for method, path in sorted(routes, key=lambda route: route[0] == "delete"):
            url, payload = request_for(path, body["id"])
            answer = client.request(method.upper(), url, **payload)
            assert answer.status_code != 403, f"{method.upper()} {url}: {answer.text}"


def test_a_watch_key_reads_its_sessions_figures_and_no_drive_key(client):
    body = client.post("/api/sessions", json={"scene": "builtin:cluster", "size": [32, 16]}).json()
    other = client.post("/api/sessions", json={"scene": "builtin:spheres"}).json()
    key = watch_key(body)
    stats = client.get(f"/api/sessions/{key}/stats")
    assert stats.status_code == 200 and stats.json()["size"] == [32, 16] and stats.json()["scene"] == "builtin:cluster"
    summary = client.get(f"/api/sessions/{key}").json()
    assert summary["size"] == [32, 16] and summary["watch_url"] == body["watch_url"]
    assert "viewer_url" not in summary and "id" not in summary
    for answer in (stats, client.get(f"/api/sessions/{key}"), client.get(f"/api/sessions/{key}/balancer"),
                   client.get(f"/api/sessions/{key}/camera")):
        assert answer.status_code == 200
        for drive_key in (body["id"], other["id"]):
            assert drive_key not in answer.text, "a watch key never leads to a drive key"
    assert client.get("/api/sessions/no-such-key/stats").status_code == 404
