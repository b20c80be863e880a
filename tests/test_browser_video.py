"""Video to the browser (issue 21) in real Chromium against a real coordinator and real nodes: with
``--stream auto`` the viewer offers the codecs its WebCodecs decoder takes and gets H.264 (VP9 with
``--stream vp9``); it paints decoded video frames while the camera moves (near ``--render-once`` of
the same camera, PSNR ≥ 30 dB) and the lossless still over them once it stops (equal to
``--render-once``); a viewer joining or reloading mid-stream gets a keyframe and paints;
``--stream tiles`` keeps today's tile frames."""

from __future__ import annotations

import base64
import io

import httpx
import numpy as np
import pytest
from PIL import Image
from playwright.sync_api import TimeoutError as PlaywrightTimeoutError

from bench.images import psnr
from tests.browser_support import DRAWN_FRACTION_JS, chromium_context
from tests.conftest import seconds
from tests.integration_support import (
    assert_matches_reference,
    camera_moving,
    orbit_cameras,
    render_once,
    scene_bounds,
    wait_until,
)
from tests.test_browser import INPUT_LATENCY_SHOWN_JS, STILL_SHOWN_JS
from tests.test_browser_sessions import CANVAS_SIZE_JS
from tests.test_browser_walls import canvas_image

pytestmark = [pytest.mark.browser, pytest.mark.integration, pytest.mark.gl]

SCENE = "builtin:spheres"
SIZE = (640, 360)
VIEWPORT = {"width": 960, "height": 540}
#: The still comes this long after the last camera change (ms): time for the page to see the last video frame.
STILL_DELAY_MS = 1000
#: Least PSNR of a decoded H.264 frame against --render-once of its camera (dB).
VIDEO_PSNR_DB = 30.0

# From now on, keep a copy of the newest video frame on the canvas (window.testVideoShot: {frameId,
# image}): looked at every few ms, a video frame is one shown while the transport is a codec, not still.
WATCH_VIDEO_JS = """() => {
  const canvas = document.getElementById("frame");
  window.testVideoShot = null;
  setInterval(() => {
    const t = window.tessera;
    if (t.transport === "tiles" || t.still || t.frameId === null) return;
    if (window.testVideoShot && window.testVideoShot.frameId === t.frameId) return;
    window.testVideoShot = {frameId: t.frameId,
      image: canvas.getContext("2d").getImageData(0, 0, canvas.width, canvas.height)};
  }, 4);
}"""

# The kept video frame as {frameId, png (data URL)}, null before one was seen.
VIDEO_SHOT_JS = """() => {
  const shot = window.testVideoShot;
  if (!shot) return null;
  const canvas = document.createElement("canvas");
  canvas.width = shot.image.width;
  canvas.height = shot.image.height;
  canvas.getContext("2d").putImageData(shot.image, 0, 0);
  return {frameId: shot.frameId, png: canvas.toDataURL("image/png")};
}"""


def data_url_image(data_url: str) -> np.ndarray:
    """(h, w, 3) uint8 of a PNG data URL."""
    return np.asarray(Image.open(io.BytesIO(base64.b64decode(data_url.split(",", 1)[1]))).convert("RGB"))


def open_viewer(context, url: str, errors: list[str]):
    page = context.new_page()
    page.on("pageerror", lambda error: errors.append(str(error)))
    page.goto(url)
    return page


def wait_js(page, expression: str, timeout_s: float = 60.0, arg=None) -> None:
    page.wait_for_function(expression, arg=arg, timeout=seconds(timeout_s) * 1000, polling=50)


def drag(page) -> None:
    """Orbit the camera by mouse: a press, twelve moves, a release."""
    box = page.locator("#frame").bounding_box()
    x, y = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    page.mouse.move(x, y)
    page.mouse.down()
    page.mouse.move(x + 120, y + 25, steps=12)
    page.mouse.up()


@pytest.mark.parametrize(("stream", "codec"), [("auto", "h264"), ("vp9", "vp9")])
def test_video_frames_near_render_once_then_the_lossless_still(coordinator_factory, tmp_path, stream, codec):
    """``--stream auto`` gives Chromium H.264; ``--stream vp9`` VP9."""
    coordinator = coordinator_factory("--scene", SCENE, "--size", f"{SIZE[0]}x{SIZE[1]}", "--local-nodes", "2",
                                      "--still-samples", "1", "--still-delay-ms", str(STILL_DELAY_MS),
                                      "--stream", stream)
    errors: list[str] = []
    with (httpx.Client(base_url=coordinator.url, timeout=seconds(30)) as client,
          chromium_context(tmp_path / "profile", viewport=VIEWPORT) as context):
        cameras = orbit_cameras(scene_bounds(client), 3)
        page = open_viewer(context, coordinator.url + "/", errors)
        wait_js(page, f"() => window.tessera.transport === '{codec}'")
        wait_js(page, f"() => document.getElementById('fig-transport').textContent.startsWith('{codec}')")
        page.evaluate(WATCH_VIDEO_JS)

        # the viewer's own drag: video frames painted, its input → display latency measured on them
        drawn_before = page.evaluate("window.tessera.framesDrawn")
        drag(page)
        wait_js(page, f"() => window.tessera.videoFramesPainted > 0 && window.tessera.framesDrawn > {drawn_before}")
        wait_js(page, INPUT_LATENCY_SHOWN_JS)
        assert page.evaluate("window.tessera.inputLatency.samples") > 0

        # known cameras: the last video frame of the last one is near render-once, the still equal to it
        for camera in cameras:
            first = client.put("/api/camera", json=camera).raise_for_status().json()["frame"]
            wait_js(page, f"() => window.tessera.frameId >= {first}")
        wait_js(page, STILL_SHOWN_JS)   # the still of the last camera: the frame shown was already >= first
        reference = render_once(SCENE, cameras[-1], SIZE, tmp_path)
        shot = page.evaluate(VIDEO_SHOT_JS)
        assert shot is not None and shot["frameId"] >= first, f"no video frame of the last camera seen: {shot}"
        video = data_url_image(shot["png"])
        assert video.shape == reference.shape
        assert psnr(video, reference) >= VIDEO_PSNR_DB, f"video frame PSNR {psnr(video, reference):.1f} dB"
        assert_matches_reference(canvas_image(page), reference, "the still painted over the video")
        assert page.evaluate("window.tessera.transport") == codec, "the still does not end the stream"
        assert page.evaluate("window.tessera.videoFramesDecoded") >= page.evaluate("window.tessera.videoFramesPainted")
        viewer_id = page.evaluate("window.tessera.viewerId")
        viewer = wait_until(lambda: next((v for v in client.get("/api/stats").json()["viewer_stats"]
                                          if v["id"] == viewer_id and v["stream_report"]), None),
                            seconds(30), f"viewer {viewer_id}'s stream_report in GET /api/stats")
        assert viewer["transport"] == codec
        assert {"bytes_per_s", "decoded_fps", "decode_queue", "frames_dropped"} <= set(viewer["stream_report"])
        streams = client.get("/api/stats").json()["video"]
        assert [s["codec"] for s in streams] == [codec], streams
        assert streams[0]["frames_encoded"] >= page.evaluate("window.tessera.videoFramesDecoded") > 0
        assert errors == [], f"errors in the page: {errors}"


def test_a_viewer_joining_or_reloading_mid_stream_gets_a_keyframe_and_paints(coordinator_factory, tmp_path):
    coordinator = coordinator_factory("--scene", SCENE, "--size", f"{SIZE[0]}x{SIZE[1]}", "--local-nodes", "1")
    errors: list[str] = []
    with (httpx.Client(base_url=coordinator.url, timeout=seconds(30)) as client,
          chromium_context(tmp_path / "profile", viewport=VIEWPORT) as context):
        camera = orbit_cameras(scene_bounds(client), 1)[0]
        first = open_viewer(context, coordinator.url + "/", errors)
        wait_js(first, "() => window.tessera.transport === 'h264'")
        with camera_moving(coordinator.url, camera):
            wait_js(first, "() => window.tessera.videoFramesPainted > 2")
            second = open_viewer(context, coordinator.url + "/", errors)
            wait_js(second, "() => window.tessera.transport === 'h264' && window.tessera.videoFramesPainted > 2")
            wait_js(second, f"() => ({DRAWN_FRACTION_JS})() > 0.02")
            first.reload()
            wait_js(first, "() => window.tessera.transport === 'h264' && window.tessera.videoFramesPainted > 2")
            wait_js(first, f"() => ({DRAWN_FRACTION_JS})() > 0.02")
        for page in (first, second):
            wait_js(page, STILL_SHOWN_JS)
        assert errors == [], f"errors in the pages: {errors}"


def test_stream_tiles_keeps_tile_frames(coordinator_factory, tmp_path):
    coordinator = coordinator_factory("--scene", SCENE, "--size", "320x180", "--local-nodes", "1",
                                      "--stream", "tiles")
    errors: list[str] = []
    with chromium_context(tmp_path / "profile", viewport=VIEWPORT) as context:
        page = open_viewer(context, coordinator.url + "/", errors)
        wait_js(page, "() => document.getElementById('fig-transport').textContent === 'tiles'")
        wait_js(page, f"() => ({DRAWN_FRACTION_JS})() > 0.02")
        drawn_before = page.evaluate("window.tessera.framesDrawn")
        drag(page)
        wait_js(page, f"() => window.tessera.framesDrawn > {drawn_before}")
        wait_js(page, STILL_SHOWN_JS)
        assert page.evaluate("window.tessera.transport") == "tiles"
        assert page.evaluate("window.tessera.videoFramesDecoded") == 0
        assert errors == [], f"errors in the page: {errors}"


def test_a_new_frame_size_reopens_the_stream_and_the_decoder_follows(coordinator_factory, tmp_path):
    """A session's driver sizes its frames to the window: a new size reopens the stream (a new
    ``stream`` message, then a keyframe of the new size), and the page decodes it at that size."""
    coordinator = coordinator_factory("--scene", SCENE, "--size", "160x120", "--local-nodes", "1",
                                      "--still-samples", "1")   # the frames not still are video frames
    errors: list[str] = []
    with (httpx.Client(base_url=coordinator.url, timeout=seconds(30)) as client,
          chromium_context(tmp_path / "profile", viewport={"width": 700, "height": 500}) as context):
        created = client.post("/api/sessions", json={"scene": SCENE, "size": [100, 50]}).raise_for_status().json()
        session = f"/api/sessions/{created['id']}"
        page = open_viewer(context, created["viewer_url"], errors)
        for viewport in ({"width": 700, "height": 500}, {"width": 520, "height": 640}):
            page.set_viewport_size(viewport)
            wanted = page.evaluate(CANVAS_SIZE_JS)
            wait_until(lambda wanted=wanted: client.get(session).json()["size"] == wanted, seconds(30),
                       f"the session to take {wanted}")
            wait_js(page, "() => window.tessera.transport === 'h264'")
            for attempt in range(6):   # a busy machine may show the still before a poll sees the video frame
                painted = page.evaluate("window.tessera.videoFramesPainted")
                drag(page)
                try:
                    wait_js(page, f"""() => window.tessera.videoFramesPainted > {painted} &&
                                           window.tessera.size[0] === {wanted[0]} &&
                                           window.tessera.size[1] === {wanted[1]} && !window.tessera.still""",
                            timeout_s=10.0)
                    break
                except PlaywrightTimeoutError:
                    if attempt == 5:
                        raise
            wait_js(page, f"() => ({DRAWN_FRACTION_JS})() > 0.02")
        assert errors == [], f"errors in the page: {errors}"
