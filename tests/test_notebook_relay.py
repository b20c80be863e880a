"""The notebook view's kernel side (issue 33) against a real coordinator, without a browser: the
comm relay passes the coordinator's frames on unchanged, never more than its window ahead of the
page's acknowledgements (the newest frame waiting), and the page's input reaches the session; the
widget's front end bundles the viewer's own modules."""

from __future__ import annotations

import os
import threading
import time
from typing import Any

import pytest
from jupyter_client.manager import KernelManager

from bench.processes import REPO
from tessera.client import Tessera
from tessera.client.frames import ViewSocket
from tessera.client.notebook import ACK_TIMEOUT_S, WINDOW, CommRelay, TesseraView
from tessera.client.widget_bundle import viewer_dir, widget_module
from tessera.wire.protocol import unpack_frame
from tests.conftest import seconds
from tests.integration_support import wait_until

pytestmark = [pytest.mark.integration, pytest.mark.gl]


def test_the_relay_keeps_to_its_window_and_forwards_the_pages_input(coordinator_factory):
    coordinator = coordinator_factory("--local-nodes", "1", "--size", "96x64")
    with Tessera(coordinator.url, timeout=seconds(60)) as tessera:
        session = tessera.open_session("builtin:spheres")
        session.snapshot(still=False)
        controls: list[dict] = []
        frames: list[tuple[float, bytes]] = []
        lock = threading.Lock()

        def frame(message: bytes, waited_s: float) -> None:
            with lock:
                frames.append((time.monotonic(), message))

        relay = CommRelay(lambda: ViewSocket(tessera.url, session.id, None, seconds(30)), controls.append, frame)
        relay.start()
        try:
            hello = wait_until(lambda: next((c for c in controls if c["type"] == "hello"), None), seconds(30), "hello")
            camera = session.camera.to_json()
            for step in range(12):   # the page turns the camera; it acknowledges nothing yet
                eye = [camera["eye"][0] + 0.05 * (step + 1), *camera["eye"][1:]]
                relay.forward({"type": "camera", "camera": {**camera, "eye": eye}, "seq": step + 1})
                # a frame for each camera until the window is full
                wait_until(lambda n=min(step + 1, WINDOW): len(frames) >= n, seconds(30), f"frame {step + 1}")
            wait_until(lambda: len(frames) >= WINDOW, seconds(30), "the window's frames")
            with lock:
                early = [at for at, _ in frames if at - frames[0][0] < ACK_TIMEOUT_S * 0.8]
            assert len(early) <= WINDOW, "no more than the window before an acknowledgement or the timeout"
            assert wait_until(lambda: session.camera.eye[0] != camera["eye"][0], seconds(30), "the page's camera")
            sent = len(frames)
            relay.acknowledged()
            relay.acknowledged()
            wait_until(lambda: relay.frames_dropped > 0 or len(frames) > sent, seconds(30), "the newest frame sent")
            parsed = [unpack_frame(message) for _, message in frames]
            assert [f.frame_id for f in parsed] == sorted(f.frame_id for f in parsed)
            assert max(f.input_seq for f in parsed) > 0, "frames answer the page's input"
            assert hello["size"] == [96, 64] or hello["size"] == list(session.size)
            relay.start()   # a page opened again gets the hello and the newest frame
            assert controls[-1]["type"] == "hello"
        finally:
            relay.stop()
        view = session.show()
        try:
            view._from_page(view, {"type": "ready"}, [])   # the page opened: the kernel joins as a viewer
            camera = session.camera.to_json()
            moved = {**camera, "eye": [camera["eye"][0] + 0.5, *camera["eye"][1:]]}
            ack = {"type": "ack", "frame": None, "messages": [{"type": "camera", "camera": moved, "seq": 1}],
                   "sent_ms": time.time() * 1000.0}
            view._from_page(view, ack, [])   # the camera the page held rides with a frame's acknowledgement
            assert wait_until(lambda: session.camera.eye[0] != camera["eye"][0], seconds(30), "the ack's camera")
            assert len(view.input_hops) == 1   # the ack's own hop: the comm's cost, page → kernel
        finally:
            view.close()


def test_the_view_is_an_anywidget_of_the_viewers_modules(coordinator_factory):
    coordinator = coordinator_factory("--size", "64x48", "--token", "view-secret")
    module = widget_module()
    assert (viewer_dir() / "compositor.js").is_file()
    for name in ("protocol", "compositor", "controls", "orbit", "latency", "session"):
        assert f"const module_{name} = " in module, f"the viewer's {name}.js is bundled"
    assert "export default" in module and 'from "./' not in module
    with Tessera(coordinator.url, token="view-secret") as tessera:
        view = tessera.view("builtin:spheres", width=300, height=200)
        assert isinstance(view, TesseraView) and (view.width, view.height, view.transport) == (300, 200, "comm")
        assert view.direct_url == "" and view.relay is not None
        direct = view.session.show(200, 100, transport="direct")
        assert direct.direct_url.startswith(coordinator.url.replace("http://", "ws://") + "/ws/view?session=")
        assert direct.direct_url.endswith("&token=view-secret") and direct.relay is None
        with pytest.raises(ValueError, match="transport"):
            view.session.show(transport="carrier-pigeon")
        view.close()
        direct.close()


def _statuses(client: Any, comm_id: str, timeout: float) -> list[str]:
    """The statuses the kernel publishes for one comm message to ``comm_id`` (until its idle)."""
    message = client.session.msg("comm_msg", {"comm_id": comm_id, "data": {"method": "custom",
                                                                          "content": {"type": "latency"}}})
    client.shell_channel.send(message)
    statuses: list[str] = []
    while not statuses or statuses[-1] != "idle":
        reply = client.get_iopub_msg(timeout=timeout)
        if reply["msg_type"] == "status" and reply["parent_header"].get("msg_id") == message["header"]["msg_id"]:
            statuses.append(reply["content"]["execution_state"])
    return statuses


def _run(client: Any, code: str, timeout: float) -> str:
    """Run ``code`` in the kernel; what it printed."""
    out: list[str] = []

    def hook(message: dict) -> None:
        if message["msg_type"] == "stream":
            out.append(message["content"]["text"])
        elif message["msg_type"] == "error":
            out.append("\n".join(message["content"]["traceback"]))

    reply = client.execute_interactive(code, timeout=timeout, output_hook=hook)
    assert reply["content"]["status"] == "ok", "".join(out)
    return "".join(out)


def test_the_kernel_answers_a_comm_views_messages_without_busy(coordinator_factory, tmp_path):
    # Each page message is a shell request: busy and idle would flip JupyterLab's kernel status (and
    # restyle the page) twice a frame. A real ipykernel: the view's comm gets idle only, another
    # widget's comm both, and the view's comm both again once the view is closed.
    coordinator = coordinator_factory("--size", "64x48")
    manager = KernelManager(kernel_name="python3")
    manager.start_kernel(cwd=str(tmp_path), env={**os.environ, "PYTHONPATH": str(REPO)})
    client = manager.client()
    client.start_channels()
    try:
        client.wait_for_ready(timeout=seconds(60))
        view_id, slider_id = _run(client, "import ipywidgets\nfrom tessera.client import Tessera\n"
                                  f"view = Tessera({coordinator.url!r}).view('builtin:spheres', width=64, height=48)\n"
                                  "slider = ipywidgets.IntSlider()\n"
                                  "print(view.comm.comm_id, slider.comm.comm_id)", seconds(60)).split()
        assert _statuses(client, view_id, seconds(30)) == ["idle"]
        assert _statuses(client, slider_id, seconds(30)) == ["busy", "idle"]
        _run(client, "view.close()", seconds(30))
        assert _statuses(client, view_id, seconds(30)) == ["busy", "idle"]
    finally:
        client.stop_channels()
        manager.shutdown_kernel(now=True)
