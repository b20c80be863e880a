"""The viewer's animation controls in headless Chromium (issue 11) against a real coordinator with
builtin:traffic and two local nodes: they appear for an animated scene, play makes frames come
without input, pause stops them, the slider jumps the scene time; a static scene shows none."""

from __future__ import annotations

import json
import urllib.request

import pytest

from tests.browser_support import DRAWN_FRACTION_JS, chromium_context
from tests.conftest import seconds
from tests.integration_support import wait_until

pytestmark = pytest.mark.browser


def animation(base_url: str) -> dict:
    with urllib.request.urlopen(f"{base_url}/api/animation", timeout=seconds(10)) as response:
        return json.load(response)


def test_play_pause_and_the_time_slider(coordinator_factory, tmp_path):
    coordinator = coordinator_factory("--local-nodes", "2", "--scene", "builtin:traffic", "--size", "320x180")
    base_url = coordinator.url
    wait_ms = seconds(60) * 1000
    with chromium_context(tmp_path / "profile", viewport={"width": 960, "height": 540}) as context:
        page = context.new_page()
        errors: list[str] = []
        page.on("pageerror", lambda error: errors.append(str(error)))
        page.goto(base_url + "/")
        page.wait_for_function(f"() => ({DRAWN_FRACTION_JS})() > 0.02", timeout=wait_ms, polling=100)
        page.wait_for_selector("#animation:not([hidden])", timeout=wait_ms)
        assert page.locator("#play").text_content() == "play"
        assert page.get_attribute("#scene-time", "max") == "80"

        page.click("#play")
        wait_until(lambda: animation(base_url)["playing"], seconds(30), "the animation to play")
        page.wait_for_function("() => document.getElementById('play').textContent === 'pause'", timeout=wait_ms)
        drawn = page.evaluate("window.tessera.framesDrawn")
        page.wait_for_function(f"() => window.tessera.framesDrawn >= {drawn + 5}", timeout=wait_ms, polling=50)
        page.wait_for_function("() => Number(document.getElementById('scene-time').value) > 0", timeout=wait_ms)

        page.click("#play")
        wait_until(lambda: not animation(base_url)["playing"], seconds(30), "the animation to pause")
        page.wait_for_function("() => window.tessera.still === true", timeout=wait_ms, polling=100)
        paused_at = animation(base_url)["time"]
        assert page.evaluate("window.tessera.animation.playing") is False
        assert animation(base_url)["time"] == paused_at, "paused: the scene time stands still"

        page.locator("#scene-time").fill("40")
        wait_until(lambda: animation(base_url)["time"] == 40.0, seconds(30), "the slider to set the time")
        page.wait_for_function("() => document.getElementById('scene-time-text').textContent === '40.0 s / 80.0 s'",
                               timeout=wait_ms)
        assert errors == [], f"errors in the page: {errors}"


def test_a_static_scene_shows_no_animation_controls(coordinator_factory, tmp_path):
    coordinator = coordinator_factory("--local-nodes", "1", "--scene", "builtin:spheres", "--size", "160x90")
    with chromium_context(tmp_path / "profile") as context:
        page = context.new_page()
        page.goto(coordinator.url + "/")
        page.wait_for_function(f"() => ({DRAWN_FRACTION_JS})() > 0.02", timeout=seconds(60) * 1000, polling=100)
        assert animation(coordinator.url)["animations"] == []
        assert page.locator("#animation").is_hidden()
