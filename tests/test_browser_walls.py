"""A display wall in real Chromium (issue 22): a real coordinator and two real nodes, four pages as
a 2×2 wall and one driver. Each cell's canvas shows its cell of the whole wall's frame (equal to
``--render-once`` of the whole wall cut at the cell, bezels left out, PSNR ≥ 50 with the lossless
codec); the cells present the same frames and their skew is in the stats; a cell that closes and
reopens rejoins at the newest frame; the driver sees the whole wall with its cells outlined."""

from __future__ import annotations

import base64
import io

import httpx
import numpy as np
import pytest
from PIL import Image

from tessera.scheduling.refinement import DEFAULT_STILL_SAMPLES
from tests.browser_support import chromium_context
from tests.conftest import seconds
from tests.integration_support import assert_matches_reference, orbit_cameras, render_once, wait_until

pytestmark = [pytest.mark.browser, pytest.mark.integration, pytest.mark.gl]

CELL = (160, 120)
WALL = {"cols": 2, "rows": 2, "cell": list(CELL), "bezel": [8, 6]}
WALL_SIZE = (2 * 160 + 8, 2 * 120 + 6)
SCENE = "builtin:cluster"
CANVAS_PNG_JS = "() => document.getElementById('frame').toDataURL('image/png')"
OUTLINED_JS = """() => {
  const canvas = document.getElementById("overlay");
  const data = canvas.getContext("2d").getImageData(0, 0, canvas.width, canvas.height).data;
  let white = 0;
  for (let i = 0; i < data.length; i += 4) if (data[i] > 200 && data[i + 1] > 200 && data[i + 3] > 200) white++;
  return white;
}"""


def canvas_image(page) -> np.ndarray:
    """The page's frame canvas, as it holds it: (h, w, 3) uint8."""
    data_url = page.evaluate(CANVAS_PNG_JS)
    return np.asarray(Image.open(io.BytesIO(base64.b64decode(data_url.split(",", 1)[1]))).convert("RGB"))


def shown_frame(page) -> int | None:
    return page.evaluate("() => window.tessera.frameId")


def test_four_pages_show_a_2x2_wall_frame_locked_and_a_reopened_cell_rejoins(coordinator_factory, tmp_path):
    coordinator = coordinator_factory("--scene", "builtin:spheres", "--size", "64x48", "--local-nodes", "2",
                                      "--codec", "png", "--max-size", "320x240")
    wait_ms = seconds(60) * 1000
    with httpx.Client(base_url=coordinator.url, timeout=seconds(30)) as client:
        created = client.post("/api/sessions", json={"scene": SCENE, "wall": WALL})
        assert created.status_code == 201, created.text
        body = created.json()
        assert body["size"] == list(WALL_SIZE)
        session = f"/api/sessions/{body['id']}"
        bounds = wait_until(lambda: client.get(f"{session}/camera").json()["bounds"], seconds(120), "the wall's scene")
        cameras = orbit_cameras(bounds, 6)
        with chromium_context(tmp_path / "profile", viewport={"width": 320, "height": 240}) as context:
            errors: list[str] = []
            pages = {}
            for cell in ((0, 0), (1, 0), (0, 1), (1, 1)):
                page = context.new_page()
                page.on("pageerror", lambda error: errors.append(str(error)))
                page.goto(f"{body['viewer_url']}&cell={cell[0]},{cell[1]}")
                pages[cell] = page
            driver = context.new_page()
            driver.goto(body["viewer_url"])

            def all_show(frame_id: int) -> None:
                for page in pages.values():
                    page.wait_for_function(f"() => window.tessera.frameId >= {frame_id}", timeout=wait_ms,
                                           polling=50)

            # the still frame of a known camera: every cell shows its cut of render-once
            first = client.put(f"{session}/camera", json=cameras[0]).raise_for_status().json()["frame"]
            still = client.get(f"{session}/frame.png", params={"after": first, "still": "true"},
                               timeout=seconds(120)).raise_for_status()
            still_id = int(still.headers["x-frame-id"])
            all_show(still_id)
            reference = render_once(SCENE, cameras[0], WALL_SIZE, tmp_path, still_samples=DEFAULT_STILL_SAMPLES)
            for (col, row), page in pages.items():
                assert shown_frame(page) == still_id, "every cell presents the same frame"
                x, y = col * (CELL[0] + 8), row * (CELL[1] + 6)
                assert_matches_reference(canvas_image(page), reference[y:y + CELL[1], x:x + CELL[0]],
                                         f"cell {col},{row}")
            driver.wait_for_function(f"() => window.tessera.frameId >= {still_id}", timeout=wait_ms)
            assert driver.evaluate("() => document.getElementById('frame').width") == WALL_SIZE[0]
            assert driver.evaluate(OUTLINED_JS) > 0, "the driver outlines the cells"

            # frames present together: the lock's skew over the moves
            for camera in cameras[1:4]:
                last = client.put(f"{session}/camera", json=camera).raise_for_status().json()["frame"]
            all_show(last)
            lock = wait_until(lambda: (s := client.get(f"{session}/stats").json()["frame_lock"])["skew_samples"] >= 2
                              and s, seconds(30), "present skews from the cells")
            assert lock["cells"] == 4 and lock["skew_p50_ms"] is not None and lock["skew_p99_ms"] >= 0.0

            # a cell that closes and reopens rejoins at the newest frame
            pages[(1, 1)].close()
            newest = client.put(f"{session}/camera", json=cameras[4]).raise_for_status().json()["frame"]
            newest_still = client.get(f"{session}/frame.png", params={"after": newest, "still": "true"},
                                      timeout=seconds(120)).raise_for_status()
            newest_id = int(newest_still.headers["x-frame-id"])
            reopened = context.new_page()
            reopened.goto(f"{body['viewer_url']}&cell=1,1")
            pages[(1, 1)] = reopened
            all_show(newest_id)
            assert {shown_frame(page) for page in pages.values()} == {newest_id}
            assert client.get(f"{session}/stats").json()["frame_lock"]["cells"] == 4
            assert errors == [], f"errors in the pages: {errors}"
