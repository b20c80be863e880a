"""The viewer's tools in headless Chromium against a real coordinator and two local nodes (issue
35): a click selects what it shows (the nodes tint it, the panel names it) and Esc clears it; a
drag is no click; the distance tool measures between two clicked points, in scene units, drawn over
the picture; a note is kept with the session; a cut clips the model; and on a phone (touch
emulation, 390x844 at devicePixelRatio 3) a tap selects, one finger orbits and two fingers pinch."""

from __future__ import annotations

import json
import math
import urllib.request

import numpy as np
import pytest

from tessera.geometry import Camera, view_projection
from tests.browser_support import DRAWN_FRACTION_JS, chromium_context
from tests.conftest import seconds, start_coordinator
from tests.integration_support import wait_ready_nodes, wait_until

pytestmark = pytest.mark.browser

SIZE = (640, 360)
CAMERA = {"eye": [0.3, 2.0, 3.8], "target": [0.0, 0.35, 0.0], "up": [0, 1, 0], "fovy_deg": 42}
MARKS_JS = """() => {
  const canvas = document.getElementById("marks");
  const data = canvas.getContext("2d").getImageData(0, 0, canvas.width, canvas.height).data;
  let painted = 0;
  for (let i = 3; i < data.length; i += 4) if (data[i] > 0) painted++;
  return painted;
}"""


@pytest.fixture(scope="module")
def coordinator():
    started = start_coordinator("--scene", "builtin:spheres", "--size", f"{SIZE[0]}x{SIZE[1]}", "--local-nodes", "2")
    try:
        import httpx
        with httpx.Client(base_url=started.url, timeout=seconds(60)) as client:
            wait_ready_nodes(client, 2)
        yield started
    finally:
        started.proc.stop()


def call(base_url: str, path: str, method: str = "GET", body=None):
    data = None if body is None else json.dumps(body).encode()
    request = urllib.request.Request(f"{base_url}{path}", data=data, method=method,
                                     headers={"content-type": "application/json"})
    with urllib.request.urlopen(request, timeout=seconds(30)) as response:
        return json.load(response)


def screen_point(page, base_url: str, point) -> tuple[float, float]:
    """Where world ``point`` shows on the page: the session camera's projection, letterboxed into #frame."""
    camera = Camera.from_json(call(base_url, "/api/camera")["camera"])
    bounds = np.asarray(call(base_url, "/api/camera")["bounds"])
    clip = view_projection(camera, SIZE, bounds) @ np.append(np.asarray(point, dtype=float), 1.0)
    px, py = (clip[0] / clip[3] + 1) / 2 * SIZE[0], (1 - clip[1] / clip[3]) / 2 * SIZE[1]
    box = page.locator("#frame").bounding_box()
    scale = min(box["width"] / SIZE[0], box["height"] / SIZE[1])
    x0, y0 = box["x"] + (box["width"] - SIZE[0] * scale) / 2, box["y"] + (box["height"] - SIZE[1] * scale) / 2
    return x0 + px * scale, y0 + py * scale


def centre_of(base_url: str, name: str) -> list[float]:
    objects = {o["name"]: o for o in call(base_url, "/api/objects")}
    return np.mean(objects[name]["bounds"], axis=0).tolist()


def open_viewer(context, base_url: str):
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    page.goto(base_url + "/")
    page.wait_for_function(f"() => ({DRAWN_FRACTION_JS})() > 0.02", timeout=seconds(60) * 1000, polling=100)
    page.wait_for_function("() => window.tessera.camera !== null", timeout=seconds(30) * 1000)
    return page, errors


def test_click_selects_esc_clears_measure_note_and_cut(coordinator, tmp_path) -> None:
    base = coordinator.url
    call(base, "/api/camera", "PUT", CAMERA)
    with chromium_context(tmp_path / "profile", viewport={"width": 1100, "height": 620}) as context:
        page, errors = open_viewer(context, base)
        wait_ms = seconds(60) * 1000
        # a drag orbits and selects nothing
        x, y = screen_point(page, base, centre_of(base, "sphere1"))
        page.mouse.move(x, y)
        page.mouse.down()
        page.mouse.move(x + 40, y + 5, steps=4)
        page.mouse.up()
        wait_until(lambda: call(base, "/api/camera")["camera"]["eye"] != CAMERA["eye"], seconds(20), "the orbit")
        assert call(base, "/api/selection") == {"object": None}
        call(base, "/api/camera", "PUT", CAMERA)
        page.wait_for_function(f"() => Math.abs(window.tessera.camera.eye[0] - {CAMERA['eye'][0]}) < 1e-9",
                               timeout=wait_ms)
        # a click selects
        page.mouse.click(*screen_point(page, base, centre_of(base, "sphere1")))
        wait_until(lambda: call(base, "/api/selection")["object"] == "sphere1", seconds(20), "the selection")
        page.wait_for_function("() => document.getElementById('selection-name').textContent === 'sphere1'",
                               timeout=wait_ms)
        # the name shows at once, the properties once the page has the scene's objects (GET …/objects)
        page.wait_for_function("() => document.getElementById('selection-props').textContent.includes('triangles')",
                               timeout=wait_ms)
        page.keyboard.press("Escape")
        wait_until(lambda: call(base, "/api/selection")["object"] is None, seconds(20), "Esc clearing the selection")
        assert page.locator("#selection").is_hidden()
        # the distance between two ground points, in scene units, drawn over the picture
        page.click("[data-tool=distance]")
        a, b = [-1.6, 0.0, 1.2], [1.5, 0.0, 1.0]
        for point in (a, b):
            page.mouse.click(*screen_point(page, base, point))
        page.wait_for_function("() => !document.getElementById('measure-result').hidden", timeout=wait_ms)
        shown = page.locator("#measure-result").text_content()
        assert shown.startswith("distance ") and shown.endswith("scene units"), shown
        assert abs(float(shown.split()[1]) - math.dist(a, b)) < 0.05 * math.dist(a, b)
        assert page.evaluate(MARKS_JS) > 50, "the measurement is drawn over the picture"
        page.keyboard.press("Escape")
        page.wait_for_function("() => document.getElementById('measure-result').hidden", timeout=wait_ms)
        # a note, kept with the session
        page.click("[data-tool=note]")
        page.fill("#note-text", "left sphere")
        page.mouse.click(*screen_point(page, base, centre_of(base, "sphere0")))
        wait_until(lambda: [n["text"] for n in call(base, "/api/annotations")] == ["left sphere"], seconds(20),
                   "the note")
        # a cut through the sphere's front
        page.click("[data-tool=cut]")
        page.mouse.click(*screen_point(page, base, centre_of(base, "sphere2")))
        wait_until(lambda: len(call(base, "/api/clip")["planes"]) == 1, seconds(20), "the cut")
        page.click("#clear-cuts")
        wait_until(lambda: not call(base, "/api/clip")["planes"], seconds(20), "the cuts cleared")
        assert not errors, errors
    call(base, "/api/annotations", "PUT", [])


def touch(client, kind: str, points: list[tuple[float, float]]) -> None:
    touches = [{"x": x, "y": y, "id": number} for number, (x, y) in enumerate(points)]
    client.send("Input.dispatchTouchEvent", {"type": kind, "touchPoints": touches})


def test_on_a_phone_a_tap_selects_one_finger_orbits_two_pinch(coordinator, tmp_path) -> None:
    base = coordinator.url
    call(base, "/api/camera", "PUT", CAMERA)
    with chromium_context(tmp_path / "profile", viewport={"width": 390, "height": 844}, device_scale_factor=3,
                          is_mobile=True, has_touch=True) as context:
        page, errors = open_viewer(context, base)
        assert page.evaluate("window.devicePixelRatio") == 3
        client = context.new_cdp_session(page)
        page.touchscreen.tap(*screen_point(page, base, centre_of(base, "sphere3")))
        wait_until(lambda: call(base, "/api/selection")["object"] == "sphere3", seconds(20), "a tap selecting")
        x, y = screen_point(page, base, [0.0, 0.3, 0.0])
        before = call(base, "/api/camera")["camera"]
        touch(client, "touchStart", [(x, y)])
        for step in range(1, 6):
            touch(client, "touchMove", [(x + 12 * step, y)])
        touch(client, "touchEnd", [])
        wait_until(lambda: call(base, "/api/camera")["camera"]["eye"] != before["eye"], seconds(20),
                   "one finger orbiting")
        assert call(base, "/api/selection")["object"] == "sphere3", "a drag is no tap"
        orbited = call(base, "/api/camera")["camera"]
        gap = lambda c: math.dist(c["eye"], c["target"])   # noqa: E731
        touch(client, "touchStart", [(x - 40, y), (x + 40, y)])
        for step in range(1, 6):
            touch(client, "touchMove", [(x - 40 - 15 * step, y), (x + 40 + 15 * step, y)])
        touch(client, "touchEnd", [])
        wait_until(lambda: gap(call(base, "/api/camera")["camera"]) < 0.9 * gap(orbited), seconds(20),
                   "two fingers spreading to zoom in")
        assert not errors, errors
    call(base, "/api/selection", "PUT", {"object": None})
