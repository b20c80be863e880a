"""``python -m bench.screenshot`` (the picture of README and docs/index.md) on a small real cluster: it starts the
coordinator with local nodes, drives the viewer in headless Chromium and writes a PNG of the page."""

from __future__ import annotations

import subprocess

import pytest
from PIL import Image

from bench.processes import PYTHON, REPO
from tests.browser_support import CHROMIUM, unavailable
from tests.conftest import seconds

pytestmark = pytest.mark.browser


def test_screenshot_writes_the_viewer_page(tmp_path):
    if not CHROMIUM.exists():
        unavailable(f"{CHROMIUM} is missing (apt-get install chromium)")
    out = tmp_path / "shot.png"
    result = subprocess.run([PYTHON, "-m", "bench.screenshot", "--out", str(out), "--nodes", "2", "--turns", "1",
                             "--viewport", "800x450", "--", "--scene", "builtin:spheres", "--size", "320x180"],
                            cwd=REPO, capture_output=True, text=True, timeout=seconds(240), check=False)
    assert result.returncode == 0, result.stdout + result.stderr
    assert result.stdout.strip() == f"wrote {out}"
    with Image.open(out) as image:
        assert image.size == (800, 450)
        # the page, not a blank: the dark panel and the lighter rendered scene both appear
        colours = image.convert("L").getcolors(maxcolors=1 << 16)
    assert colours is not None and len(colours) > 50
