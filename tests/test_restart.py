"""The coordinator restarts (Ctrl-C, or killed outright) on the same port: real render nodes and the
real viewer in headless Chromium reconnect by themselves, and frames resume, exact.

Two nodes run as processes of their own (not ``--local-nodes``, which would die with the
coordinator); the camera keeps moving through ``PUT /api/camera`` across the restart. The viewer's
reconnect is the page's own ``Connection`` (web/connection.js, its back-off unit-tested in
tests/js/connection.test.mjs). Missing Playwright or Chromium skips the test, except in CI.
"""

from __future__ import annotations

import contextlib
import math
import signal
import socket
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from bench.processes import LoggedProcess, orbit
from tests.browser_support import chromium_context
from tests.conftest import PYTHON, Coordinator, seconds, start_coordinator, start_process
from tests.integration_support import assert_matches_reference, fetch_frame, ready_nodes, render_once, wait_until

pytestmark = [pytest.mark.integration, pytest.mark.gl, pytest.mark.browser]

SCENE = "builtin:spheres"
SIZE = (160, 120)

# Every state the page's status badge takes from now on ("connecting", "open", "closed").
WATCH_STATUS_JS = """() => {
  const status = document.getElementById("status");
  window.testStates = [status.dataset.state];
  new MutationObserver(() => window.testStates.push(status.dataset.state))
    .observe(status, {attributes: true, attributeFilter: ["data-state"]});
}"""


def free_port() -> int:
    """A loopback port free right now (the coordinator binds it with SO_REUSEADDR)."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def start_server(port: int) -> Coordinator:
    return start_coordinator("--host", "127.0.0.1", "--scene", SCENE, "--size", f"{SIZE[0]}x{SIZE[1]}",
                             "--codec", "png", port=port)


class CameraMover:
    """A user turning the camera: ``PUT /api/camera`` ``hz`` times a second on a thread of its own.
    While the coordinator is down the requests fail; they are counted, not raised."""

    def __init__(self, base_url: str, camera: dict[str, Any], hz: float = 20.0) -> None:
        self.base_url, self.camera, self.hz = base_url, camera, hz
        self.accepted = self.failed = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        step = 0
        with httpx.Client(base_url=self.base_url, timeout=seconds(5)) as client:
            while not self._stop.wait(1.0 / self.hz):
                step += 1
                try:
                    client.put("/api/camera", json=orbit(self.camera, 0.3 * math.sin(step / 10))).raise_for_status()
                    self.accepted += 1
                except httpx.HTTPError:
                    self.failed += 1

    @contextlib.contextmanager
    def running(self) -> Iterator[CameraMover]:
        self._thread.start()
        try:
            yield self
        finally:
            self._stop.set()
            self._thread.join(timeout=seconds(30))


@pytest.fixture
def processes() -> Iterator[list[LoggedProcess]]:
    """Processes a test starts; all stopped at teardown (already stopped ones are skipped)."""
    started: list[LoggedProcess] = []
    yield started
    for proc in reversed(started):
        proc.stop()


def both_ready(base_url: str) -> bool:
    with httpx.Client(base_url=base_url, timeout=seconds(10)) as client:
        try:
            return len(ready_nodes(client)) == 2
        except httpx.HTTPError:
            return False


@pytest.mark.parametrize("how", ["SIGINT", "SIGKILL"])
def test_nodes_and_viewer_reconnect_after_a_coordinator_restart(how: str, processes: list[LoggedProcess],
                                                                tmp_path: Path) -> None:
    port = free_port()
    coordinator = start_server(port)
    processes.append(coordinator.proc)
    for index in (1, 2):
        processes.append(start_process([PYTHON, "-m", "node", "--coordinator", f"ws://127.0.0.1:{port}/ws/node",
                                        "--name", f"restart-{index}"], env={"LP_NUM_THREADS": "1"}))
    url, first = coordinator.url, coordinator
    wait_until(lambda: both_ready(url), seconds(120), "both nodes ready")
    with httpx.Client(base_url=url, timeout=seconds(30)) as client:
        camera = client.get("/api/camera").raise_for_status().json()["camera"]

    wait_ms = seconds(60) * 1000
    with chromium_context(tmp_path / "chromium-profile") as context, \
            CameraMover(url, camera).running() as mover:
        page = context.new_page()
        errors: list[str] = []
        page.on("pageerror", lambda error: errors.append(str(error)))
        page.goto(url + "/")
        page.wait_for_function("() => window.tessera.connected && window.tessera.framesDrawn > 2",
                               timeout=wait_ms, polling=100)
        page.evaluate(WATCH_STATUS_JS)

        if how == "SIGINT":
            assert coordinator.proc.stop() == 0, coordinator.proc.output()
        else:
            coordinator.proc.process.send_signal(signal.SIGKILL)
            coordinator.proc.stop()
        page.wait_for_function("() => !window.tessera.connected", timeout=wait_ms, polling=50)
        drawn_while_down = page.evaluate("window.tessera.framesDrawn")
        accepted_while_down = mover.accepted

        coordinator = start_server(port)
        processes.append(coordinator.proc)
        wait_until(lambda: both_ready(url), seconds(60), "both nodes back in /api/stats after the restart")
        page.wait_for_function(f"() => window.tessera.connected && window.tessera.framesDrawn > {drawn_while_down + 2}",
                               timeout=wait_ms, polling=100)
        wait_until(lambda: mover.accepted > accepted_while_down, seconds(30), "camera PUTs accepted again")
        states = page.evaluate("window.testStates")
        assert "closed" in states and states[-1] == "open", states
        assert errors == [], errors

    with httpx.Client(base_url=url, timeout=seconds(30)) as client:
        target = orbit(camera, 0.8)
        frame_after = client.put("/api/camera", json=target).raise_for_status().json()["frame"]
        frame_id, image = fetch_frame(client, frame_after)
        assert frame_id >= frame_after
        assert_matches_reference(image, render_once(SCENE, target, SIZE, tmp_path), f"frame {frame_id} after {how}")
        nodes = client.get("/api/stats").json()["nodes"]
        assert sorted(n["name"] for n in nodes) == ["restart-1", "restart-2"], (nodes, coordinator.proc.output())
    for proc in (first.proc, coordinator.proc):
        assert "Traceback" not in proc.output(), proc.output()
    for proc in processes[1:3]:   # the nodes: each reconnected once, for the restart, and was never closed
        assert proc.output().count("connected to ws://") == 2, proc.output()
