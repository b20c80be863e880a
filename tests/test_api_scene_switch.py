"""``PUT /api/sessions/{id}/scene`` (issue 33's ``Session.set_scene``) and the links behind a proxy
(``--root-path``, ``X-Forwarded-Prefix``), in process with a fake node: a switched session's viewer
sees the old scene's frames whole, then the new scene's, never a frame of both."""

from __future__ import annotations

import dataclasses

import pytest
from fastapi.testclient import TestClient

from server.app import create_app
from server.origins import path_prefix, public_base
from server.settings import load_settings
from tessera.wire.codec import decode
from tessera.wire.protocol import unpack_frame
from tests.conftest import seconds
from tests.test_api import next_json
from tests.test_api_sessions import SETTINGS, SceneNode

pytestmark = pytest.mark.timeout(seconds(120))
CAMERA = {"eye": [0, 0, 5], "target": [0, 0, 0]}


def frame_levels(message: bytes) -> set[int]:
    """The grey levels of a frame's tiles (the fake node draws each scene at its own level)."""
    frame = unpack_frame(message)
    return {int(decode(payload, entry.codec, entry.rect.w, entry.rect.h)[0, 0, 0]) for entry, payload in frame.tiles}


def test_a_switched_session_shows_the_old_scene_whole_then_the_new_one():
    with TestClient(create_app(SETTINGS)) as client:
        session_id = client.post("/api/sessions", json={"scene": "builtin:cluster", "size": [64, 32],
                                                        "camera": CAMERA}).json()["id"]
        with client.websocket_connect("/ws/node") as node_ws, \
                client.websocket_connect(f"/ws/view?session={session_id}") as viewer:
            node = SceneNode(node_ws)
            next_json(viewer, "hello")
            first = client.put(f"/api/sessions/{session_id}/camera", json=CAMERA).json()["frame"]
            node.serve(lambda render: render["scene"] == "builtin:cluster" and render["frame"] >= first)
            switched = client.put(f"/api/sessions/{session_id}/scene", json={"scene": "builtin:traffic"})
            assert switched.status_code == 200, switched.text
            assert switched.json()["scene"] == "builtin:traffic"
            renders = node.serve(lambda render: render["scene"] == "builtin:traffic")
            assert next(r["frame"] for r in renders if r["scene"] == "builtin:traffic") >= switched.json()["frame"]
            assert node.scenes[-1] == "builtin:traffic"
            switched_renders = [r for r in renders if r["scene"] == "builtin:traffic"]   # not the default session's
            assert all(r["camera"]["eye"] == CAMERA["eye"] for r in switched_renders), "the camera is kept"
            old, new = 40 * (node.scenes.index("builtin:cluster") + 1), 40 * (node.scenes.index("builtin:traffic") + 1)
            seen: list[int] = []
            while new not in seen:
                message = viewer.receive()
                if message.get("bytes"):
                    levels = frame_levels(message["bytes"])
                    assert len(levels) == 1, f"a frame of two scenes: {levels}"
                    seen.append(levels.pop())
            assert set(seen) <= {old, new} and seen.index(new) == len(seen) - 1
        summary = client.get(f"/api/sessions/{session_id}").json()
        assert summary["scene"] == "builtin:traffic" and summary["size"] == [64, 32]


def test_bad_scene_switches_are_refused_with_the_reason():
    with TestClient(create_app(SETTINGS)) as client:
        session_id = client.post("/api/sessions", json={"scene": "builtin:cluster"}).json()["id"]
        unknown = client.put(f"/api/sessions/{session_id}/scene", json={"scene": "library/nope.glb"})
        assert unknown.status_code == 422 and "nope.glb" in unknown.text
        bad_camera = {"scene": "builtin:spheres", "camera": {"eye": [0, 0, 0], "target": [0, 0, 0]}}
        assert client.put(f"/api/sessions/{session_id}/scene", json=bad_camera).status_code == 422
        assert client.put("/api/sessions/nope/scene", json={"scene": "builtin:spheres"}).status_code == 404
        default = client.put("/api/sessions/default/scene", json={"scene": "builtin:cluster"})
        assert default.status_code == 409 and "--scene" in default.text
        assert client.get(f"/api/sessions/{session_id}").json()["scene"] == "builtin:cluster", "nothing changed"


@pytest.mark.parametrize(("text", "prefix"), [
    ("/tessera", "/tessera"), ("/tessera/", "/tessera"), ("/proxy/8000/", "/proxy/8000"), ("/a, /b", "/a"),
    ("", ""), (None, ""), ("tessera", ""), ("//evil.example", ""), ("/a/../b", ""), ("https://evil.example/x", ""),
    ("/a?b", ""), ("/a\r\nSet-Cookie: x", ""), ("/a b", "")])
def test_path_prefixes_are_plain_paths_or_none(text, prefix):
    assert path_prefix(text) == prefix


def test_the_public_base_follows_the_proxy_then_the_root_path():
    assert public_base("http", "127.0.0.1:8000") == "http://127.0.0.1:8000/"
    assert public_base("http", "127.0.0.1:8000", "/base") == "http://127.0.0.1:8000/base/"
    assert public_base("http", "internal:8000", "/base", "https", "example.org", "/tessera/") == \
        "https://example.org/tessera/"
    assert public_base("http", "example.org", "", None, None, "//evil.example") == "http://example.org/"
    assert load_settings(["--root-path", "/tessera/"], {}).root_path == "/tessera"
    with pytest.raises(SystemExit):
        load_settings(["--root-path", "https://elsewhere/"], {})


def test_links_and_the_token_cookie_carry_the_prefix():
    settings = dataclasses.replace(SETTINGS, root_path="/base", token="secret")
    with TestClient(create_app(settings)) as client:
        auth = {"Authorization": "Bearer secret"}
        plain = client.post("/api/sessions", json={"scene": "builtin:cluster"}, headers=auth).json()
        assert plain["viewer_url"] == f"http://testserver/base/?session={plain['id']}"
        forwarded = {"X-Forwarded-Prefix": "/proxy/8000", "X-Forwarded-Host": "hub.example",
                     "X-Forwarded-Proto": "https"}
        proxied = client.get(f"/api/sessions/{plain['id']}", headers={**auth, **forwarded})
        assert proxied.json()["viewer_url"] == f"https://hub.example/proxy/8000/?session={plain['id']}"
        assert proxied.json()["watch_url"].startswith("https://hub.example/proxy/8000/?session=")
        page = client.get("/?token=secret", headers={"X-Forwarded-Prefix": "/tessera"})
        assert page.status_code == 200 and "Path=/tessera/" in page.headers["set-cookie"]
        assert "Path=/base/" in client.get("/?token=secret").headers["set-cookie"]
