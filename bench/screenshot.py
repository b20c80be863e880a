"""The picture of README and the manual's front page, made from the real viewer:
``python -m bench.screenshot [--out PNG]``.

Starts ``python -m server --local-nodes N`` (every other setting its default unless given), opens
the viewer in Debian's headless Chromium through Playwright (no browser download), turns the camera
by mouse drags as a user would (3 s each, paced like a hand), waits until the still frame is on
screen and the panel shows the cluster at rest with every node's bar, and writes a screenshot of
the page (default docs/screenshot.png). The PNG records, as text chunks, when it was made and a
digest of the files that lay out the page and its panel (:data:`VIEWER_FILES`): ``tests/test_docs.py``
fails once they change, until this command is run again.
"""

from __future__ import annotations

import argparse
import datetime
import hashlib
import os
import sys
from pathlib import Path

from PIL import Image, PngImagePlugin

from bench.processes import REPO, start_coordinator

CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--no-first-run"]
DEFAULT_OUT = REPO / "docs" / "screenshot.png"
#: The files that lay out the viewer page and its panel: a picture made before one of them changed
#: shows a page users no longer see.
VIEWER_FILES = ("web/index.html", "web/style.css", "web/panel.js")
#: PNG text keys: the digest of VIEWER_FILES the picture was made with, and the UTC date it was made.
DIGEST_KEY = "tessera-viewer-sha256"
MADE_KEY = "tessera-made"
#: Drags before the picture: the first frames after start-up are slow (nodes warming up), later
#: ones show the figures a user meets while turning the camera.
DEFAULT_TURNS = 3

# The page is ready for its picture: a frame drawn and still, the panel at rest with a bar per
# node (render segments drawn: a node that drew little may have one too narrow to show; no bar
# still animating) and the input → display latency known.
READY_JS = """(nodes) =>
  window.tessera && window.tessera.framesDrawn > 0 && window.tessera.still === true &&
  !document.getElementById("render-state").hidden &&
  /^\\d+ ms/.test(document.getElementById("fig-input-latency").textContent) &&
  document.querySelectorAll("#nodes li").length === nodes &&
  [...document.querySelectorAll("#nodes .seg.render")].some((seg) => seg.offsetWidth > 0) &&
  document.getAnimations().every((animation) => animation.playState !== "running")"""


def viewer_digest() -> str:
    """SHA-256 over the names and bytes of :data:`VIEWER_FILES` as they are now."""
    digest = hashlib.sha256()
    for name in VIEWER_FILES:
        digest.update(name.encode() + b"\0" + (REPO / name).read_bytes())
    return digest.hexdigest()


def stamp(path: Path) -> None:
    """Write into the PNG at ``path`` the viewer's digest and today's date (UTC)."""
    with Image.open(path) as image:
        image.load()
        info = PngImagePlugin.PngInfo()
        info.add_text(DIGEST_KEY, viewer_digest())
        info.add_text(MADE_KEY, datetime.datetime.now(datetime.UTC).date().isoformat())
        image.save(path, pnginfo=info, optimize=True)


def size(text: str) -> tuple[int, int]:
    width, _, height = text.lower().partition("x")
    return int(width), int(height)


def take_screenshot(out: Path, nodes: int, viewport: tuple[int, int], server_args: list[str],
                    turns: int = DEFAULT_TURNS, timeout_s: float = 120.0) -> None:
    """Run a coordinator with ``nodes`` local nodes and ``server_args``, drive its viewer in a
    ``viewport`` (width, height px) page by ``turns`` drags and write the page's screenshot to
    ``out`` (PNG)."""
    os.environ["PLAYWRIGHT_SKIP_BROWSER_DOWNLOAD"] = "1"
    from playwright.sync_api import sync_playwright

    if not CHROMIUM.exists():
        raise SystemExit(f"{CHROMIUM} is missing (apt-get install chromium)")
    coordinator, url = start_coordinator(["--local-nodes", str(nodes), *server_args], timeout=timeout_s,
                                         new_session=True)
    try:
        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
            try:
                page = browser.new_page(viewport={"width": viewport[0], "height": viewport[1]})
                page.goto(url + "/")
                wait_ms = timeout_s * 1000
                page.wait_for_function("() => window.tessera && window.tessera.framesDrawn > 0", timeout=wait_ms)
                page.wait_for_function("() => window.tessera.still === true", timeout=wait_ms, polling=100)
                box = page.locator("#frame").bounding_box()
                assert box is not None
                x, y = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
                for turn in range(turns):
                    # a user's drag: a small move every 40 ms for 3 s, at rest again before the next
                    page.mouse.move(x, y)
                    page.mouse.down()
                    for step in range(1, 76):
                        page.mouse.move(x + (-1) ** turn * 2 * step, y + step // 5)
                        page.wait_for_timeout(40)
                    page.mouse.up()
                    page.wait_for_function(READY_JS, arg=nodes, timeout=wait_ms, polling=100)
                page.mouse.move(0, 0)
                out.parent.mkdir(parents=True, exist_ok=True)
                page.screenshot(path=str(out))
                stamp(out)
            finally:
                browser.close()
    finally:
        coordinator.stop()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.screenshot", description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"PNG to write (default {DEFAULT_OUT})")
    parser.add_argument("--nodes", type=int, default=3, help="local render nodes (default 3)")
    parser.add_argument("--turns", type=int, default=DEFAULT_TURNS,
                        help=f"camera drags before the picture (default {DEFAULT_TURNS})")
    parser.add_argument("--viewport", type=size, default=(1280, 720), help="browser page WxH (default 1280x720)")
    parser.add_argument("server_args", nargs=argparse.REMAINDER,
                        help="after --: more python -m server flags, e.g. -- --scene builtin:spheres")
    args = parser.parse_args(argv)
    extra = args.server_args[1:] if args.server_args[:1] == ["--"] else args.server_args
    take_screenshot(args.out, args.nodes, args.viewport, extra, args.turns)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
