"""What a new user meets in the viewer (issue 38), in headless Chromium against real coordinators:

* a watch link only watches: its panel shows its own session's figures, offers no control that
  changes anything, and trying every control it has (and dragging, scrolling, keys, a dropped file)
  sends no change and changes neither the watched session nor the shared one;
* messages stay until dismissed or the next action, and the panel offers what the coordinator
  allows (how to fill an empty library, how to turn uploads on);
* the panel's figures agree with the picture (frame id, size, the scene's name shortened with the
  full name on hover) and the picker shows the session's scene;
* a link to a session that does not exist (or was closed) says so, links to the shared session and
  stops trying.
"""

from __future__ import annotations

import contextlib
import json
import re
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.browser_support import DRAWN_FRACTION_JS, chromium_context
from tests.conftest import REPO, seconds
from tests.integration_support import wait_until
from tests.scene_files_support import TRIANGLE_PLY

pytestmark = [pytest.mark.browser, pytest.mark.integration, pytest.mark.gl]

#: Every control of the page a user can see: what the watch page's test tries.
VISIBLE_CONTROLS_JS = """() => [...document.querySelectorAll("button, select, input, a[href]")]
  .filter((element) => element.checkVisibility() && !element.disabled)
  .map((element, index) => {
    element.dataset.tried = String(index);
    return {index, tag: element.tagName.toLowerCase(), type: element.type || "", id: element.id,
            options: element.tagName === "SELECT" ? [...element.options].map((o) => o.value) : []};
  })"""
#: The frame figure, the badge and the canvas size read at one instant.
FIGURES_JS = """() => ({figure: document.getElementById("fig-frame").textContent,
  badge: document.getElementById("frame-badge").textContent,
  size: document.getElementById("fig-size").textContent,
  canvas: `${document.getElementById("frame").width}×${document.getElementById("frame").height}`})"""
#: The viewer's first reconnect delay (web/connection.js), ms.
FIRST_RETRY_MS = int(re.search(r"FIRST_RETRY_MS = (\d+)", (REPO / "web" / "connection.js").read_text()).group(1))
NOTES_MS = int(re.search(r"NOTES_MS = (\d+)", (REPO / "web" / "tools.js").read_text()).group(1))


def call(base_url: str, path: str, body: dict | None = None, method: str | None = None) -> Any:
    data = None if body is None else json.dumps(body).encode()
    request = urllib.request.Request(f"{base_url}{path}", data=data, method=method,
                                     headers={"content-type": "application/json"})
    with urllib.request.urlopen(request, timeout=seconds(10)) as response:
        return json.load(response) if response.status != 204 else None


def watched_state(base: str, session_id: str) -> dict[str, Any]:
    """What any change would show: the driven session's and the shared session's camera, size,
    balancer, scene and animation clock (its time left out: it runs), the sessions and the scenes."""
    def of(prefix: str) -> dict[str, Any]:
        summary = call(base, f"{prefix}/stats")
        clock = call(base, f"{prefix}/animation")
        return {"camera": call(base, f"{prefix}/camera")["camera"], "size": summary["size"],
                "balancer": call(base, f"{prefix}/balancer")["name"], "scene": summary["scene"],
                "playing": clock["playing"], "speed": clock["speed"]}

    return {"driven": of(f"/api/sessions/{session_id}"), "shared": of("/api"),
            "sessions": sorted(s["id"] for s in call(base, "/api/sessions")),
            "scenes": call(base, "/api/scenes")}


def drop_file(page, name: str, content: bytes) -> None:
    transfer = page.evaluate_handle("""([name, bytes]) => {
      const transfer = new DataTransfer();
      transfer.items.add(new File([new Uint8Array(bytes)], name));
      return transfer;
    }""", [name, list(content)])
    page.dispatch_event("body", "drop", {"dataTransfer": transfer})


#: The stats polls the page made so far (resource timing, its buffer made large enough by BUFFER_JS).
POLLS_JS = """() => performance.getEntriesByType("resource").filter((e) => /\\/stats$/.test(e.name)).length"""
#: Every request to the coordinator's API the page made so far.
API_CALLS_JS = """() => performance.getEntriesByType("resource").filter((e) => e.name.includes("/api/")).length"""
BUFFER_JS = "performance.setResourceTimingBufferSize(100000)"


def wait_polls(page, count: int) -> int:
    """Wait until the page made ``count`` more stats polls (it kept running meanwhile); how many it made."""
    wanted = page.evaluate(POLLS_JS) + count
    page.wait_for_function(f"() => ({POLLS_JS})() >= {wanted}", timeout=seconds(30) * 1000, polling=100)
    return wanted


@contextlib.contextmanager
def viewer_page(profile: Path, width: int, height: int) -> Iterator[tuple[Any, list[str]]]:
    """A page of a fresh Chromium that counts its stats polls (:data:`POLLS_JS`), and the list of
    errors raised in it."""
    with chromium_context(profile, viewport={"width": width, "height": height}) as context:
        page = context.new_page()
        page.add_init_script(BUFFER_JS)
        errors: list[str] = []
        page.on("pageerror", lambda error: errors.append(str(error)))
        yield page, errors


def test_a_watch_link_only_watches(coordinator_factory, tmp_path):
    coordinator = coordinator_factory("--scene", "builtin:spheres", "--size", "160x120", "--local-nodes", "1")
    base = coordinator.url
    created = call(base, "/api/sessions", {"scene": "builtin:traffic", "size": [200, 100]})
    wait_until(lambda: all(s["state"] == "ready" for s in call(base, "/api/sessions")), seconds(120),
               "the node to load the session's scene and the shared one's (after it: the new session goes first)")
    before = watched_state(base, created["id"])
    wait_ms = seconds(60) * 1000
    with viewer_page(tmp_path / "profile", 900, 600) as (page, errors):
        changes: list[str] = []
        page.on("request", lambda request: changes.append(f"{request.method} {request.url}")
                if request.method not in ("GET", "HEAD") else None)
        sent: list[str] = []
        page.on("websocket", lambda ws: ws.on("framesent", lambda payload: sent.append(str(payload))))
        page.goto(created["watch_url"])
        page.wait_for_function(f"() => ({DRAWN_FRACTION_JS})() > 0.02", timeout=wait_ms, polling=100)
        page.wait_for_function("() => !document.getElementById('animation').hidden", timeout=wait_ms)
        wait_polls(page, 1)

        # Its own session's figures, and nothing that steers.
        assert page.text_content("#fig-size") == "200×100", "the watched session's size, not the shared one's"
        shown = page.evaluate(FIGURES_JS)
        assert shown["figure"] == shown["badge"].removeprefix("frame ") and shown["size"] == shown["canvas"]
        assert page.text_content("#balancer-name") == before["driven"]["balancer"]
        line = page.text_content("#session-name")
        assert line.startswith("watching · builtin:traffic · 200×100") and "cannot steer" in line, line
        for steering in ("#balancer", "#new-session", "#scene-pick", "#reset-view", "#play", "#scene-time",
                         "#upload-hint", "#drive-link"):
            assert not page.is_visible(steering), f"a watch page shows {steering}"
        assert page.input_value("#watch-link") == created["watch_url"]
        assert created["id"] not in page.content(), "the watch page holds no drive key"

        # Try everything: each visible control, the picture (drag, wheel, double-click), keys, a dropped file.
        controls = page.evaluate(VISIBLE_CONTROLS_JS)
        assert {control["id"] for control in controls} >= {"toggle-overlay", "watch-link"}
        for control in controls:
            selector = f"[data-tried='{control['index']}']"
            if control["tag"] == "select":
                for value in control["options"]:
                    page.select_option(selector, value)
            elif control["tag"] == "input" and control["type"] not in ("checkbox", "radio", "range", "button"):
                page.fill(selector, "typed") if page.is_editable(selector) else page.click(selector)
            elif control["tag"] != "a":
                page.click(selector)
        box = page.locator("#frame").bounding_box()
        x, y = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
        page.mouse.move(x, y)
        page.mouse.down()
        for step in range(10):
            page.mouse.move(x + 8 * step, y + 3 * step)
        page.mouse.up()
        page.mouse.wheel(0, 400)
        page.mouse.dblclick(x, y)
        for key in ("r", "R", "o", "O"):
            page.keyboard.press(key)
        drop_file(page, "box.ply", TRIANGLE_PLY)
        page.wait_for_function("() => !document.getElementById('panel-message').hidden", timeout=wait_ms)
        assert "watches a session" in page.text_content("#panel-message-text")
        wait_polls(page, 2)

        assert changes == [], f"the watch page asked for changes: {changes}"
        steering_frames = [frame for frame in sent if re.search(r'"type":\s*"(camera|size)"', frame)]
        assert steering_frames == [], f"the watch page sent {steering_frames[:3]}"
        assert watched_state(base, created["id"]) == before, "neither session changed"
        assert errors == [], f"errors in the page: {errors}"


def test_messages_stay_and_the_panel_offers_what_the_coordinator_allows(coordinator_factory, tmp_path):
    data, library = tmp_path / "data", tmp_path / "library"
    data.mkdir()
    library.mkdir()
    coordinator = coordinator_factory("--scene", "builtin:spheres", "--size", "160x120", "--local-nodes", "1",
                                      "--data-dir", str(data), "--scenes-dir", str(library))
    base = coordinator.url
    off = coordinator_factory("--scene", "builtin:spheres", "--size", "160x120", "--data-dir", "none")
    urllib.request.urlopen(urllib.request.Request(
        f"{base}/api/scenes", data=b"--b\r\nContent-Disposition: form-data; name=\"file\"; filename=\"box.ply\"\r\n\r\n"
        + TRIANGLE_PLY + b"\r\n--b--\r\n", headers={"content-type": "multipart/form-data; boundary=b"}),
        timeout=seconds(60))
    wait_ms = seconds(60) * 1000
    with viewer_page(tmp_path / "profile", 900, 600) as (page, errors):
        page.goto(base + "/")
        page.wait_for_function("() => document.querySelectorAll('#scene-pick option').length > 1", timeout=wait_ms)

        # The picker shows the session's scene, and says how to fill the empty library.
        page.wait_for_function("() => document.getElementById('scene-pick').value === 'builtin:spheres'",
                               timeout=wait_ms)
        assert page.evaluate("document.getElementById('scene-pick').selectedOptions[0].textContent") == \
            "builtin:spheres · shown now"
        hint = page.text_content("#library-hint")
        assert page.is_visible("#library-hint") and str(library.resolve()) in hint and "put GLB" in hint, hint
        assert "drop a scene file" in page.text_content("#upload-hint")
        assert "512 MiB" in page.text_content("#upload-hint")

        # A refusal stays through the stats polls, until dismissed...
        drop_file(page, "box.ply", TRIANGLE_PLY)
        page.wait_for_function("() => /refused/.test(document.getElementById('panel-message-text').textContent)",
                               timeout=wait_ms)
        wait_polls(page, 4)
        assert page.is_visible("#panel-message")
        assert page.text_content("#panel-message-text") == \
            "box.ply refused: a scene named 'upload/box.ply' exists already"
        page.click("#dismiss-message")
        assert not page.is_visible("#panel-message")
        # ...or until the next thing the user does.
        drop_file(page, "box.ply", TRIANGLE_PLY)
        page.wait_for_function("() => !document.getElementById('panel-message').hidden", timeout=wait_ms)
        wait_polls(page, 2)
        assert page.is_visible("#panel-message")
        page.select_option("#balancer", "static")
        page.wait_for_function("() => document.getElementById('panel-message').hidden", timeout=wait_ms)
        assert call(base, "/api/balancer")["name"] == "static"

        # Uploads off: the panel says how to turn them on, and a dropped file is not sent.
        posts: list[str] = []
        page.on("request", lambda request: posts.append(request.url) if request.method == "POST" else None)
        page.goto(off.url + "/")
        page.wait_for_function("() => /--data-dir/.test(document.getElementById('upload-hint').textContent)",
                               timeout=wait_ms)
        assert page.text_content("#upload-hint") == "uploads are off: start the coordinator with --data-dir DIR " \
                                                    "to turn them on"
        drop_file(page, "mine.ply", TRIANGLE_PLY)
        page.wait_for_function("() => !document.getElementById('panel-message').hidden", timeout=wait_ms)
        assert page.text_content("#panel-message-text").startswith("mine.ply not uploaded: uploads are off")
        assert posts == []
        assert errors == [], f"errors in the page: {errors}"


def test_the_panel_agrees_with_the_picture_and_a_bad_link_says_so(coordinator_factory, tmp_path):
    library = tmp_path / "library"
    folder = library / "a_folder_with_a_long_name" / "and_another_one_below_it"
    folder.mkdir(parents=True)
    long_name = "a_scene_file_whose_name_runs_on_and_on_and_on.ply"
    (folder / long_name).write_bytes(TRIANGLE_PLY)
    full_name = f"library/a_folder_with_a_long_name/and_another_one_below_it/{long_name}"
    coordinator = coordinator_factory("--scene", "builtin:spheres", "--size", "160x120", "--local-nodes", "1",
                                      "--scenes-dir", str(library), "--max-size", "1280x960")
    base = coordinator.url
    created = call(base, "/api/sessions", {"scene": full_name})
    wait_ms = seconds(60) * 1000
    with viewer_page(tmp_path / "profile", 700, 500) as (page, errors):
        sockets: list[str] = []
        page.on("websocket", lambda ws: sockets.append(ws.url))
        page.goto(created["viewer_url"])
        page.wait_for_function(f"() => ({DRAWN_FRACTION_JS})() > 0.02", timeout=wait_ms, polling=100)
        # The session follows the window: the figures follow the picture, not the size it was opened at.
        page.wait_for_function("() => document.getElementById('frame').width !== 1280", timeout=wait_ms)
        wait_polls(page, 2)
        shown = page.evaluate(FIGURES_JS)
        assert shown["figure"] == shown["badge"].removeprefix("frame "), shown
        assert shown["size"] == shown["canvas"] == "×".join(map(str, call(base, f"/api/sessions/{created['id']}")
                                                                 ["size"])), shown
        line = page.text_content("#session-name")
        assert line.startswith("your session · ") and line.endswith(shown["size"]) and "…" in line, line
        assert len(line.split(" · ")[1]) <= 30
        assert page.get_attribute("#session-name", "title") == f"scene: {full_name}"
        assert page.get_attribute("#scene-pick option:checked", "title") == full_name

        # The session is closed under the page: it says so, links on, and stops trying.
        call(base, f"/api/sessions/{created['id']}", method="DELETE")
        page.wait_for_function("() => !document.getElementById('gone').hidden", timeout=wait_ms)
        assert "does not exist" in page.text_content("#gone")
        assert page.get_attribute("#gone a", "href") == "./"
        tried, asked = len(sockets), page.evaluate(API_CALLS_JS)
        # An absence: past the first reconnects a live page makes and past a period of its notes' poll.
        page.wait_for_timeout(max(4 * FIRST_RETRY_MS, NOTES_MS + 1000))
        assert (len(sockets), page.evaluate(API_CALLS_JS)) == (tried, asked), "no more tries, no more requests"

        # A link to a session that never was: 404, the same words, one try.
        sockets.clear()
        answer = page.goto(f"{base}/?session=no-such-session")
        assert answer is not None and answer.status == 404
        page.wait_for_function("() => !document.getElementById('gone').hidden", timeout=wait_ms)
        assert page.text_content("#status-text") == "no such session"
        page.click("#gone a")
        page.wait_for_url(f"{base}/", timeout=wait_ms)
        page.wait_for_function(f"() => ({DRAWN_FRACTION_JS})() > 0.02", timeout=wait_ms, polling=100)
        assert len(sockets) == 2, sockets
        assert errors == [], f"errors in the page: {errors}"


def test_the_server_answers_a_bad_link_with_404(coordinator_factory):
    coordinator = coordinator_factory("--scene", "builtin:spheres", "--size", "64x48")
    with pytest.raises(urllib.error.HTTPError) as missing:
        urllib.request.urlopen(f"{coordinator.url}/?session=nope", timeout=seconds(10))
    assert missing.value.code == 404 and b"No such session" in missing.value.read()
    watch = call(coordinator.url, "/api/sessions/default")["watch_url"]
    with urllib.request.urlopen(watch, timeout=seconds(10)) as page:
        assert page.status == 200, "the shared session's watch link exists"
