"""The notebook view (issue 33) in a real ``jupyter lab`` driven by headless Chromium. The kernel
reaches the coordinator through nginx under a path prefix; the page can reach neither (every attempt
is refused): the frames come through the kernel's comm, a drag in the cell moves the session's
camera, and the view shows the still badge and its stats line."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bench.jupyter import VIEW_STATE_JS, jupyter_lab, run_first_cells, write_notebook
from tessera.client import Tessera
from tests.browser_support import chromium_context
from tests.conftest import seconds
from tests.integration_support import wait_until
from tests.notebook_support import blocking
from tests.proxy_support import nginx_prefix

pytestmark = [pytest.mark.browser, pytest.mark.integration, pytest.mark.gl]

VIEW = (320, 240)
CANVAS_SPREAD_JS = """() => {
  const canvas = document.querySelector(".tessera-frame");
  const data = canvas.getContext("2d").getImageData(0, 0, canvas.width, canvas.height).data;
  let lo = 255, hi = 0;
  for (let i = 0; i < data.length; i += 4) { lo = Math.min(lo, data[i + 1]); hi = Math.max(hi, data[i + 1]); }
  return hi - lo;
}"""


def test_the_notebook_view_shows_frames_through_the_comm_and_a_drag_moves_the_camera(coordinator_factory, tmp_path):
    coordinator = coordinator_factory("--scene", "builtin:spheres", "--size", "160x120", "--local-nodes", "1")
    upstream = coordinator.url.split("//", 1)[1].rstrip("/")
    root = tmp_path / "notebooks"
    root.mkdir()
    wait_ms = seconds(90) * 1000
    with nginx_prefix(upstream, "/tessera", tmp_path / "nginx", seconds(30)) as proxied:
        write_notebook(root / "view.ipynb", [
            "from tessera.client import Tessera\n"
            f"tessera = Tessera({proxied!r})\n"
            "session = tessera.open_session('builtin:spheres')\n"
            f"view = session.show({VIEW[0]}, {VIEW[1]})\n"
            "view"])
        with jupyter_lab(root, seconds(90)) as lab, Tessera(proxied) as observer, \
                chromium_context(tmp_path / "profile", viewport={"width": 1100, "height": 800}) as context:
            refused = blocking(context, upstream) + blocking(context, proxied.split("//", 1)[1].split("/", 1)[0])
            page = context.new_page()
            errors: list[str] = []
            page.on("pageerror", lambda error: errors.append(str(error)))
            page.goto(lab.open_url("view.ipynb"))
            run_first_cells(page, 1, wait_ms)
            page.wait_for_function(f"() => {{ const s = ({VIEW_STATE_JS})(); return s && s.framesDrawn > 0; }}",
                                   timeout=wait_ms, polling=200)
            # The session opened at the coordinator's --size; the view asks for its cell × dpr 1.
            page.wait_for_function(f"() => ({VIEW_STATE_JS})().size.join('x') === '{VIEW[0]}x{VIEW[1]}'",
                                   timeout=wait_ms, polling=200)
            state = page.evaluate(VIEW_STATE_JS)
            assert state["transport"] == "comm"
            assert page.evaluate(CANVAS_SPREAD_JS) > 40, "a picture, not a blank canvas"
            page.wait_for_selector(".tessera-badge[data-quality='still']", timeout=wait_ms)
            page.wait_for_function("() => document.querySelector('.tessera-stats').textContent.includes('frame')",
                                   timeout=wait_ms)
            [info] = [s for s in observer.sessions() if s.id != "default"]
            session = observer.session(info.id)
            before = session.camera
            drawn_before = state["framesDrawn"]

            box = page.locator(".tessera-frame").bounding_box()
            x, y = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
            page.mouse.move(x, y)
            page.mouse.down()
            for step in range(1, 9):   # each step once the view has taken the last (its camera changed)
                camera = page.evaluate(f"() => JSON.stringify(({VIEW_STATE_JS})().camera)")
                page.mouse.move(x + 12 * step, y + 2 * step, steps=2)
                page.wait_for_function(f"() => JSON.stringify(({VIEW_STATE_JS})().camera) !== {json.dumps(camera)}",
                                       timeout=wait_ms, polling=20)
            page.mouse.up()
            moved = wait_until(lambda: session.camera if session.camera.eye != before.eye else None, seconds(30),
                               "the drag to move the session's camera")
            assert moved.target == before.target
            assert np.linalg.norm(np.subtract(moved.eye, moved.target)) == pytest.approx(
                np.linalg.norm(np.subtract(before.eye, before.target)), rel=1e-6), "an orbit keeps the distance"
            page.wait_for_function(f"() => ({VIEW_STATE_JS})().framesDrawn > {drawn_before}", timeout=wait_ms)
            page.wait_for_function(f"() => ({VIEW_STATE_JS})().inputLatency !== null", timeout=wait_ms)
            assert refused == [], f"the page tried to reach the coordinator: {refused}"
            assert errors == [], f"errors in the page: {errors}"
