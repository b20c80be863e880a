"""A session in real Chromium (issue 19): the drive link shows the session's scene and its frames
follow the window (canvas × devicePixelRatio); the watch link shows the same frames."""

from __future__ import annotations

import json
import urllib.request

import pytest
import trimesh

from tests.browser_support import DRAWN_FRACTION_JS, chromium_context
from tests.conftest import seconds
from tests.integration_support import wait_until

pytestmark = [pytest.mark.browser, pytest.mark.integration, pytest.mark.gl]

CANVAS_SIZE_JS = """() => {
  const canvas = document.getElementById("frame");
  return [Math.round(canvas.clientWidth * devicePixelRatio), Math.round(canvas.clientHeight * devicePixelRatio)];
}"""


def call(base_url: str, path: str, body: dict | None = None) -> dict:
    data = None if body is None else json.dumps(body).encode()
    request = urllib.request.Request(f"{base_url}{path}", data=data, headers={"content-type": "application/json"})
    with urllib.request.urlopen(request, timeout=seconds(10)) as response:
        return json.load(response)


def test_a_session_page_follows_the_window_and_its_watch_link_shows_it(coordinator_factory, tmp_path):
    coordinator = coordinator_factory("--scene", "builtin:spheres", "--size", "160x120", "--local-nodes", "1",
                                      "--max-size", "1280x960")
    base = coordinator.url
    created = call(base, "/api/sessions", {"scene": "builtin:cluster", "size": [100, 50]})
    session = f"/api/sessions/{created['id']}"
    wait_ms = seconds(60) * 1000
    with chromium_context(tmp_path / "profile", viewport={"width": 700, "height": 500}) as context:
        page = context.new_page()
        errors: list[str] = []
        page.on("pageerror", lambda error: errors.append(str(error)))
        page.goto(created["viewer_url"])
        page.wait_for_function(f"() => ({DRAWN_FRACTION_JS})() > 0.02", timeout=wait_ms, polling=100)
        wanted = page.evaluate(CANVAS_SIZE_JS)
        wait_until(lambda: call(base, session)["size"] == wanted, seconds(30), f"the session to take {wanted}")
        page.wait_for_function(f"() => document.getElementById('frame').width === {wanted[0]}", timeout=wait_ms)
        page.set_viewport_size({"width": 520, "height": 640})
        resized = page.evaluate(CANVAS_SIZE_JS)
        assert resized != wanted
        wait_until(lambda: call(base, session)["size"] == resized, seconds(30), f"the session to follow to {resized}")
        page.wait_for_function(f"() => document.getElementById('frame').width === {resized[0]}", timeout=wait_ms)
        assert call(base, "/api/sessions/default")["size"] == [160, 120], "the default session keeps --size"

        watcher = context.new_page()
        watcher.goto(created["watch_url"])
        watcher.wait_for_function(f"() => ({DRAWN_FRACTION_JS})() > 0.02", timeout=wait_ms, polling=100)
        assert watcher.evaluate("document.getElementById('frame').width") == resized[0]
        assert call(base, session)["size"] == resized, "a watcher's window does not size the session"
        assert call(base, session)["viewers"] == 2
        assert errors == [], f"errors in the page: {errors}"


def test_a_new_session_from_the_library_and_a_dropped_file_open_in_the_page(coordinator_factory, tmp_path):
    data_dir = tmp_path / "data"
    data_dir.mkdir()
    coordinator = coordinator_factory("--scene", "builtin:spheres", "--size", "160x120", "--local-nodes", "1",
                                      "--data-dir", str(data_dir))
    base = coordinator.url
    wait_ms = seconds(60) * 1000
    box_ply = trimesh.creation.box(extents=(1.0, 2.0, 0.5)).export(file_type="ply")
    with chromium_context(tmp_path / "profile", viewport={"width": 700, "height": 500}) as context:
        page = context.new_page()
        errors: list[str] = []
        page.on("pageerror", lambda error: errors.append(str(error)))
        page.goto(base + "/")
        page.wait_for_function("() => document.querySelectorAll('#scene-pick option').length > 1", timeout=wait_ms)
        page.select_option("#scene-pick", "builtin:cluster")
        # The session's scene, once the stats say it, leaves the user's pick alone.
        page.wait_for_function("() => document.getElementById('session-name').title === 'scene: builtin:spheres'",
                               timeout=wait_ms)
        assert page.input_value("#scene-pick") == "builtin:cluster"
        page.click("#new-session")
        page.wait_for_url("**/?session=*", timeout=wait_ms)
        page.wait_for_function(f"() => ({DRAWN_FRACTION_JS})() > 0.02", timeout=wait_ms, polling=100)
        page.wait_for_function("() => !document.getElementById('session-links').hidden", timeout=wait_ms)
        drive = page.input_value("#drive-link")
        assert drive == page.url and "watch=1" in page.input_value("#watch-link")
        assert {s["scene"] for s in call(base, "/api/sessions")} == {"builtin:spheres", "builtin:cluster"}

        dropped = page.evaluate_handle("""(bytes) => {
          const transfer = new DataTransfer();
          transfer.items.add(new File([new Uint8Array(bytes)], "box.ply"));
          return transfer;
        }""", list(box_ply))
        page.dispatch_event("body", "drop", {"dataTransfer": dropped})
        page.wait_for_function(f"() => location.href !== {json.dumps(drive)}", timeout=wait_ms)
        page.wait_for_function(f"() => ({DRAWN_FRACTION_JS})() > 0.02", timeout=wait_ms, polling=100)
        scenes = {s["scene"] for s in call(base, "/api/sessions")}
        assert "upload/box.ply" in scenes, scenes
        page.wait_for_function("() => document.getElementById('session-name').title === 'scene: upload/box.ply'",
                               timeout=wait_ms)
        assert page.text_content("#session-name").startswith("your session · box.ply · ")
        assert errors == [], f"errors in the page: {errors}"
