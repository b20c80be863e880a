"""The viewer in headless Chromium against a real coordinator with two local render nodes.

Uses Debian's /usr/bin/chromium through Playwright (never a downloaded browser). Missing
Playwright or Chromium skips the test, except in CI (CI=true), where it fails. The picture of
README and the manual's front page comes from ``python -m bench.screenshot``.
"""

from __future__ import annotations

import json
import math
import re
import urllib.request
from pathlib import Path

import pytest
from PIL import Image

from tests.browser_support import DRAWN_FRACTION_JS, chromium_context
from tests.conftest import seconds
from tests.integration_support import wait_until
from tests.test_web_mirror import WEB, js_const

pytestmark = pytest.mark.browser

VIEWPORT = {"width": 960, "height": 540}

SNAPSHOT_JS = """() => {
  const canvas = document.getElementById("frame");
  window.testSnapshot = canvas.getContext("2d").getImageData(0, 0, canvas.width, canvas.height).data;
}"""

# Mean absolute difference (0…255) between the frame canvas now and the snapshot.
CHANGE_SINCE_SNAPSHOT_JS = """() => {
  const canvas = document.getElementById("frame");
  const data = canvas.getContext("2d").getImageData(0, 0, canvas.width, canvas.height).data;
  const before = window.testSnapshot;
  if (before.length !== data.length) return 255;
  let sum = 0;
  for (let i = 0; i < data.length; i++) sum += Math.abs(data[i] - before[i]);
  return sum / data.length;
}"""

# Overlay pixels: the painted fraction, and how many distinct colours the strongest ones have.
OVERLAY_JS = """() => {
  const canvas = document.getElementById("overlay");
  const data = canvas.getContext("2d").getImageData(0, 0, canvas.width, canvas.height).data;
  let painted = 0;
  const strokes = new Set();
  for (let i = 0; i < data.length; i += 4) {
    if (data[i + 3] > 0) painted++;
    if (data[i + 3] > 200) strokes.add((data[i] << 16) | (data[i + 1] << 8) | data[i + 2]);
  }
  return {painted: painted / (canvas.width * canvas.height), strokeColours: strokes.size};
}"""

# Per palette colour ('#rrggbb'), how many strongly painted overlay pixels are nearest to it (and
# within 64 summed over the channels: outlines are blended a little with the tints under them).
OVERLAY_COLOUR_COUNTS_JS = """(palette) => {
  const canvas = document.getElementById("overlay");
  const data = canvas.getContext("2d").getImageData(0, 0, canvas.width, canvas.height).data;
  const colours = palette.map((colour) => [1, 3, 5].map((i) => parseInt(colour.slice(i, i + 2), 16)));
  const counts = palette.map(() => 0);
  for (let i = 0; i < data.length; i += 4) {
    if (data[i + 3] <= 200) continue;
    const distances = colours.map((rgb) => rgb.reduce((sum, value, c) => sum + Math.abs(data[i + c] - value), 0));
    const nearest = distances.indexOf(Math.min(...distances));
    if (distances[nearest] <= 64) counts[nearest]++;
  }
  return counts;
}"""

# The panel shows the viewer's own input → display latency as a number ("48 ms · 1.3 fr").
INPUT_LATENCY_SHOWN_JS = """() => /^\\d+ ms/.test(document.getElementById("fig-input-latency").textContent)"""

# The frame on screen is the converged still frame, in the badge (with its samples: as many as the
# hello said the coordinator accumulates, at most that many for an adaptive still; a one-sample still
# is not accumulated: 0) and in window.tessera.
STILL_SHOWN_JS = """() => {
  const badge = document.getElementById("quality-badge");
  const { samples, stillSamples, stillAdaptive } = window.tessera;
  return badge.dataset.quality === "still" && window.tessera.still === true &&
    badge.textContent === (samples > 1 ? `still · ${samples} samples` : "still") &&
    (stillAdaptive ? samples > 1 && samples <= stillSamples : samples === (stillSamples > 1 ? stillSamples : 0));
}"""

# From now on, every text the quality badge shows, in order, in window.badgesShown.
RECORD_BADGES_JS = """() => {
  const badge = document.getElementById("quality-badge");
  window.badgesShown = [];
  new MutationObserver(() => {
    if (window.badgesShown.at(-1) !== badge.textContent) window.badgesShown.push(badge.textContent);
  }).observe(badge, { childList: true, characterData: true, subtree: true });
}"""

# Every node's timing bar shows its render segment and no bar is still animating.
BARS_SETTLED_JS = """() =>
  [...document.querySelectorAll("#nodes .seg.render")].every((seg) => seg.offsetWidth > 0) &&
  document.getAnimations().every((animation) => animation.playState !== "running")"""


@pytest.fixture
def chromium(tmp_path):
    """Debian's Chromium driven by Playwright, with a fresh profile and the test viewport."""
    with chromium_context(tmp_path / "chromium-profile", viewport=VIEWPORT) as context:
        yield context


def get_json(base_url: str, path: str) -> dict:
    with urllib.request.urlopen(f"{base_url}{path}", timeout=seconds(10)) as response:
        return json.load(response)


def same_camera(a: dict, b: dict) -> bool:
    return all(math.isclose(x, y, rel_tol=1e-9, abs_tol=1e-9)
               for key in ("eye", "target", "up") for x, y in zip(a[key], b[key], strict=True))


def viewer_input_latency(base_url: str, viewer_id: int) -> dict:
    """The input → display latency viewer ``viewer_id`` reported, as ``GET /api/stats`` shows it."""
    viewers = get_json(base_url, "/api/stats")["viewer_stats"]
    return next((v["input_latency"] for v in viewers if v["id"] == viewer_id), {})


def drive_viewer(context, base_url: str, screenshot: Path, nodes: int) -> None:
    """Open the viewer, wait for the scene, orbit by mouse, see the input → display latency and the
    still frame after release, toggle the overlay, take a screenshot."""
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    wait_ms = seconds(60) * 1000
    try:
        page.goto(base_url + "/")
        page.wait_for_function(f"() => ({DRAWN_FRACTION_JS})() > 0.02", timeout=wait_ms, polling=100)
        assert page.evaluate("window.tessera.connected") is True
        assert page.locator("#status").get_attribute("data-state") == "open"

        before = get_json(base_url, "/api/camera")["camera"]
        frame_before = page.evaluate("window.tessera.frameId")
        page.evaluate(SNAPSHOT_JS)
        page.evaluate(RECORD_BADGES_JS)
        box = page.locator("#frame").bounding_box()
        x, y = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
        page.mouse.move(x, y)
        page.mouse.down()
        page.mouse.move(x + 120, y + 25, steps=12)
        page.mouse.up()

        viewer_camera = page.evaluate("window.tessera.camera")
        assert not same_camera(viewer_camera, before), "dragging did not move the viewer's camera"
        wait_until(lambda: same_camera(get_json(base_url, "/api/camera")["camera"], viewer_camera), seconds(30),
                 "the coordinator to adopt the viewer's camera (GET /api/camera)")
        page.wait_for_function(
            f"() => window.tessera.frameId > {frame_before} && ({CHANGE_SINCE_SNAPSHOT_JS})() > 2",
            timeout=wait_ms, polling=100,
        )
        page.wait_for_function(INPUT_LATENCY_SHOWN_JS, timeout=wait_ms, polling=100)
        assert page.evaluate("window.tessera.inputLatency.samples") > 0
        page.wait_for_function(STILL_SHOWN_JS, timeout=wait_ms, polling=100)
        shown = page.evaluate("window.badgesShown")
        assert "interactive" in shown, shown
        badges = shown[len(shown) - shown[::-1].index("interactive"):]   # since the last interactive frame
        most, converged = page.evaluate("[window.tessera.stillSamples, window.tessera.samples]")
        assert page.evaluate("window.tessera.stillAdaptive"), "the default still is adaptive"
        refining = [int(text.split()[2]) for text in badges if text.startswith("refining")]
        assert all(re.fullmatch(r"refining · \d+ samples", text) for text in badges if text.startswith("refining"))
        assert refining and refining == sorted(refining) and max(refining) < converged <= most, badges
        assert badges[-1] == f"still · {converged} samples", badges
        viewer_id = page.evaluate("window.tessera.viewerId")
        wait_until(lambda: viewer_input_latency(base_url, viewer_id).get("samples", 0) > 0, seconds(30),
                   f"GET /api/stats to show viewer {viewer_id}'s input → display latency")

        page.check("#toggle-overlay")
        overlay = page.evaluate(OVERLAY_JS)
        assert overlay["painted"] > 0.2, f"the tile overlay covers too little of the view: {overlay}"
        assert overlay["strokeColours"] >= min(nodes, 2), f"tiles of {nodes} nodes in one colour: {overlay}"
        page.wait_for_function(f"() => document.querySelectorAll('#nodes li').length === {nodes}",
                               timeout=wait_ms, polling=100)
        page.wait_for_function("() => document.getElementById('fig-fps').textContent !== '–'",
                               timeout=wait_ms, polling=100)
        page.wait_for_function(BARS_SETTLED_JS, timeout=wait_ms, polling=50)
        page.screenshot(path=str(screenshot))

        page.uncheck("#toggle-overlay")
        assert page.evaluate(OVERLAY_JS)["painted"] == 0

        available = get_json(base_url, "/api/balancer")["available"]
        assert page.locator("#balancer option").all_text_contents() == available
        page.select_option("#balancer", available[-1])
        wait_until(lambda: get_json(base_url, "/api/balancer")["name"] == available[-1], seconds(30),
                 f"PUT /api/balancer to select {available[-1]!r}")
        assert errors == [], f"errors in the page: {errors}"
    finally:
        page.close()


def test_viewer_shows_scene_orbits_and_draws_tile_overlay(chromium, coordinator_factory, tmp_path):
    coordinator = coordinator_factory("--local-nodes", "2", "--scene", "builtin:spheres", "--size", "640x360")
    screenshot = tmp_path / "screenshot.png"
    drive_viewer(chromium, coordinator.url, screenshot, nodes=2)
    with Image.open(screenshot) as image:
        assert image.size == (VIEWPORT["width"], VIEWPORT["height"])


def test_viewer_opened_with_the_token_keeps_it_in_a_cookie_not_in_the_address_bar(chromium, coordinator_factory):
    coordinator = coordinator_factory("--local-nodes", "1", "--scene", "builtin:spheres", "--size", "320x180",
                                      "--token", "br0wser")
    page = chromium.new_page()
    try:
        page.goto(coordinator.url + "/?token=br0wser")
        page.wait_for_function(f"() => ({DRAWN_FRACTION_JS})() > 0.02", timeout=seconds(60) * 1000, polling=100)
        assert "token" not in page.url, page.url
        page.wait_for_function("() => document.getElementById('fig-fps').textContent !== '–'",
                               timeout=seconds(60) * 1000, polling=100)
        page.reload()
        page.wait_for_function("() => window.tessera.connected && window.tessera.framesDrawn > 0",
                               timeout=seconds(60) * 1000, polling=100)
        cookies = {c["name"]: c for c in chromium.cookies()}
        assert cookies["tessera_token"]["httpOnly"] and cookies["tessera_token"]["value"] == "br0wser"
    finally:
        page.close()


def test_the_overlay_outlines_where_each_node_drew_in_sort_last(chromium, coordinator_factory):
    """A sort-last frame is merged from every node's layer, so no tile of it has one node: the
    overlay outlines each node's read-back rect from GET /api/stats instead, in the node's colour."""
    coordinator = coordinator_factory("--mode", "sort-last", "--local-nodes", "2", "--scene", "builtin:spheres",
                                      "--size", "320x180")

    def drawing_nodes() -> list[dict]:
        return [n for n in get_json(coordinator.url, "/api/stats")["nodes"] if n["readback"]]

    wait_until(lambda: len(drawing_nodes()) == 2, seconds(60), "both nodes to draw part of the frame (readback)")
    palette = re.findall(r'"(#[0-9a-f]{6})"', js_const((WEB / "overlay.js").read_text(), "NODE_COLORS"))
    drawn = sorted(node["slot"] % len(palette) for node in drawing_nodes())
    page = chromium.new_page()
    try:
        page.goto(coordinator.url + "/")
        page.wait_for_function(f"() => ({DRAWN_FRACTION_JS})() > 0.02", timeout=seconds(60) * 1000, polling=100)
        page.check("#toggle-overlay")
        page.wait_for_function(
            f"([palette, drawn]) => {{ const counts = ({OVERLAY_COLOUR_COUNTS_JS})(palette); "
            "return counts.every((count, i) => (count > 50) === drawn.includes(i)); }",
            arg=[palette, drawn], timeout=seconds(30) * 1000, polling=100)
    finally:
        page.close()
