"""The viewer's panel explains itself (issue 23), in headless Chromium against a real coordinator
with two local render nodes: at rest it says so instead of "fps 0.0", and hovering each figure
(fps, the latencies, imbalance, the bar scale, a node's speed factor, the bar phases) finds its
explanation."""

from __future__ import annotations

import re

import pytest

from tests.browser_support import DRAWN_FRACTION_JS, chromium_context
from tests.conftest import seconds

pytestmark = pytest.mark.browser

# The hover text at the centre of the element ``selector``: the title of the innermost element
# there that has one (what the browser's tooltip shows).
HOVER_TITLE_JS = """(selector) => {
  const box = document.querySelector(selector).getBoundingClientRect();
  const under = document.elementFromPoint(box.left + box.width / 2, box.top + box.height / 2);
  const titled = under && under.closest("[title]");
  return titled ? titled.title : null;
}"""

# Once the rest line is shown: its text and the fps figure's, as one poll of /api/stats left them.
REST_SHOWN_JS = """() => {
  const state = document.getElementById("render-state");
  return state.hidden ? null : {state: state.textContent, fps: document.getElementById("fig-fps").textContent};
}"""

# The node row (1-based) whose render segment is widest, once one is at least 4 px wide.
WIDEST_RENDER_SEGMENT_JS = """() => {
  const widths = [...document.querySelectorAll("#nodes .seg.render")].map((segment) => segment.offsetWidth);
  const widest = Math.max(0, ...widths);
  return widest >= 4 && document.getAnimations().length === 0 ? widths.indexOf(widest) + 1 : null;
}"""

#: What hovering each figure must explain: the element hovered and words its explanation holds.
EXPLAINED = {
    "fps": ("#fig-fps", r"on demand"),
    "publish latency": ("#fig-latency", r"camera input reaching the coordinator"),
    "input → display": ("#fig-input-latency", r"camera input in this browser .* frame intervals"),
    "imbalance": ("#fig-imbalance", r"busiest node's time ÷ the mean"),
    "imbalance avg": ("#fig-imbalance-avg", r"last 60 frames"),
    "bar scale": ("#bar-scale", r"full bar width is this many ms"),
    "a node's speed": ("#nodes li:first-child .detail", r"its speed measured at start-up"),
    "the legend": (".legend li:nth-child(3)", r"encode: compressing"),
    "the rest line": ("#render-state", r"drawn only when the camera"),
}


@pytest.fixture
def chromium(tmp_path):
    with chromium_context(tmp_path / "chromium-profile", viewport={"width": 960, "height": 540}) as context:
        yield context


def test_panel_says_at_rest_and_explains_every_figure_on_hover(chromium, coordinator_factory):
    coordinator = coordinator_factory("--local-nodes", "2", "--scene", "builtin:spheres", "--size", "480x270")
    page = chromium.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    wait_ms = seconds(60) * 1000
    page.goto(coordinator.url + "/")
    page.wait_for_function(f"() => ({DRAWN_FRACTION_JS})() > 0.02", timeout=wait_ms, polling=100)
    page.wait_for_function("() => document.querySelectorAll('#nodes li').length === 2", timeout=wait_ms,
                           polling=100)

    # Nothing moves: once the first frames are 2 s old the panel says the cluster is at rest.
    # (Read in one evaluation: a later stats poll may show frames again, e.g. for a resize.)
    shown = page.wait_for_function(REST_SHOWN_JS, timeout=wait_ms, polling=100).json_value()
    assert shown == {"state": "at rest — rendering on demand", "fps": "at rest"}

    # Explanations: every figure's hover text, found by hovering it (a bar's render phase: the widest,
    # as a node that drew little has a segment too narrow to point at).
    widest = page.wait_for_function(WIDEST_RENDER_SEGMENT_JS, timeout=wait_ms, polling=100).json_value()
    explained = {**EXPLAINED, "a bar's render phase": (f"#nodes li:nth-child({widest}) .seg.render",
                                                       r"render [\d.]+ ms: drawing its tiles")}
    for what, (selector, words) in explained.items():
        page.wait_for_selector(selector, state="visible", timeout=wait_ms)   # the rest line: back at rest (a
        page.hover(selector)                                                # node's calibration may draw again)
        title = page.evaluate(HOVER_TITLE_JS, selector)
        assert title is not None and re.search(words, title), f"hovering {what} ({selector}) shows {title!r}"

    # Dragging renders: the rest line goes and fps is a number again.
    box = page.locator("#frame").bounding_box()
    x, y = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    page.mouse.move(x, y)
    page.mouse.down()
    for step in range(40):
        page.mouse.move(x + 4 * step, y + step % 7)
        page.wait_for_timeout(25)
        if page.locator("#render-state").is_hidden():
            break
    page.mouse.up()
    page.wait_for_function("() => /^\\d+\\.\\d$/.test(document.getElementById('fig-fps').textContent)",
                           timeout=wait_ms, polling=50)
    # ...and once it stops, the panel comes back to rest.
    page.wait_for_function("() => !document.getElementById('render-state').hidden", timeout=wait_ms, polling=100)
    assert errors == [], f"errors in the page: {errors}"
