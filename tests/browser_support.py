"""Headless Chromium for the viewer tests: Debian's browser driven by Playwright (no browser
download), a fresh profile every time, and the canvas check both viewer tests use."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator, Sequence
from pathlib import Path

import pytest

CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--no-first-run"]

# Fraction of the frame canvas's pixels that differ clearly from its top-left (background) pixel.
DRAWN_FRACTION_JS = """() => {
  const canvas = document.getElementById("frame");
  if (!window.tessera || !window.tessera.framesDrawn) return 0;
  const data = canvas.getContext("2d").getImageData(0, 0, canvas.width, canvas.height).data;
  const [r, g, b] = data;
  let differing = 0;
  for (let i = 0; i < data.length; i += 4) {
    if (Math.abs(data[i] - r) + Math.abs(data[i + 1] - g) + Math.abs(data[i + 2] - b) > 48) differing++;
  }
  return differing / (canvas.width * canvas.height);
}"""


def unavailable(message: str) -> None:
    """Skip for a missing tool, except in CI (CI=true), where the test must run."""
    if os.environ.get("CI") == "true":
        pytest.fail(message)
    pytest.skip(message)


@contextlib.contextmanager
def chromium_context(profile_dir: Path, args: Sequence[str] = (), **context_options) -> Iterator:
    """A Playwright browser context on Debian's Chromium with a fresh ``--user-data-dir``; ``args``
    are command-line switches added to ``CHROMIUM_ARGS``."""
    os.environ["PLAYWRIGHT_SKIP_BROWSER_DOWNLOAD"] = "1"
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        unavailable("playwright is not installed (pip install playwright; no browser download needed)")
    if not CHROMIUM.exists():
        unavailable(f"{CHROMIUM} is missing (apt-get install chromium)")
    with sync_playwright() as playwright:
        context = playwright.chromium.launch_persistent_context(
            str(profile_dir), executable_path=str(CHROMIUM), args=[*CHROMIUM_ARGS, *args], **context_options)
        try:
            yield context
        finally:
            context.close()
