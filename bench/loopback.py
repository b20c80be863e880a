"""The loopback part of ``python -m bench.scale``: a real coordinator over loopback with many
synthetic nodes and a closed-loop viewer, in this process.

One run with K nodes (``bench.scale`` makes one for each K of ``--loopback-nodes``):
``python -m server --port 0 --size WxH --log-level warning`` (every default, no local nodes), K
synthetic nodes in one process (:mod:`bench.synthetic_nodes`: pre-encoded tiles, no GL), and in this
process a closed-loop viewer on ``/ws/view`` that sends a new camera (orbiting ±0.2 rad, with
``seq``) each time a frame arrives and at least every 5 ms. After ``--warmup-s``, over
``--seconds``: published frames/s (``/api/stats`` ``coordinator_cpu.frames``), tiles/s (the nodes'
``tiles_rendered``), the coordinator process's CPU per frame (``/proc/PID/stat`` utime + stime) and
its receive / publish handler CPU per frame (``coordinator_cpu``), the synthetic nodes' process CPU
per frame; the coordinator's ceiling = 1000 / its CPU ms per frame frames/s, × tiles per frame
tiles/s. That is an extrapolation that errs low: per-second costs (the viewer's ≥ 200 cameras/s,
the stats requests) are charged to the frames measured, which the coordinator's default frame-rate
cap (60/s) holds down. Then ``GET /api/frame.png`` checks that a frame composites whole.
``--timeout-s`` bounds the whole loopback part; every process is stopped (SIGINT, then SIGKILL) on
the way out, errors included.
"""

from __future__ import annotations

import asyncio
import contextlib
import io
import json
import math
import time
from typing import Any

import httpx
from PIL import Image
from websockets.asyncio.client import ClientConnection, connect

from bench.processes import PYTHON, LoggedProcess, cpu_seconds, orbit, start_coordinator
from tessera.wire.messages import CameraUpdate

#: the viewer's longest pause between two cameras (s)
INPUT_PERIOD_S = 0.005
#: the viewer's camera swings ± this many radians about the target
ORBIT_RAD = 0.2
#: how long the synthetic nodes may take to be ready and calibrated (s)
READY_TIMEOUT_S = 60.0


class ClosedLoopViewer:
    """A viewer on ``/ws/view``: a new camera each time a frame arrives, and at least every
    :data:`INPUT_PERIOD_S`; counts frames and bytes received and inputs sent."""

    def __init__(self) -> None:
        self.frames = 0
        self.bytes = 0
        self.inputs = 0

    async def run(self, ws: ClientConnection) -> None:
        hello = json.loads(await ws.recv())
        camera = hello["camera"]
        frame_came = asyncio.Event()

        async def read() -> None:
            async for message in ws:
                if isinstance(message, bytes):
                    self.frames += 1
                    self.bytes += len(message)
                    frame_came.set()

        reader = asyncio.create_task(read())
        try:
            while not reader.done():
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(INPUT_PERIOD_S):
                        await frame_came.wait()
                frame_came.clear()
                self.inputs += 1
                turned = orbit(camera, ORBIT_RAD * math.sin(self.inputs / 40.0))
                await ws.send(CameraUpdate(camera=turned, seq=self.inputs).to_text())
            await reader
        finally:
            reader.cancel()


async def wait_ready(http: httpx.AsyncClient, nodes: int, timeout: float) -> None:
    """Until ``nodes`` nodes are ready and calibrated and a frame was published."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        stats = (await http.get("/api/stats")).raise_for_status().json()
        ready = [n for n in stats["nodes"] if n["state"] == "ready" and n["calibration_ms"] is not None]
        if len(ready) == nodes and stats["frame"] > 0:
            return
        await asyncio.sleep(0.1)
    raise RuntimeError(f"{nodes} synthetic nodes not ready and calibrated within {timeout:.0f} s")


async def snapshot(http: httpx.AsyncClient, viewer: ClosedLoopViewer, coordinator_pid: int,
                   nodes_pid: int) -> dict[str, Any]:
    stats = (await http.get("/api/stats")).raise_for_status().json()
    return {"at": time.monotonic(), "stats": stats, "coordinator_cpu_s": cpu_seconds([coordinator_pid]),
            "nodes_cpu_s": cpu_seconds([nodes_pid]), "viewer_frames": viewer.frames, "viewer_bytes": viewer.bytes,
            "viewer_inputs": viewer.inputs}


def loopback_figures(before: dict[str, Any], after: dict[str, Any]) -> dict[str, Any]:
    """The window's figures from two :func:`snapshot` s; RuntimeError when no frame was published."""
    elapsed = after["at"] - before["at"]
    cpu0, cpu1 = before["stats"]["coordinator_cpu"], after["stats"]["coordinator_cpu"]
    frames = cpu1["frames"] - cpu0["frames"]
    if frames <= 0:
        raise RuntimeError(f"the coordinator published no frame in {elapsed:.1f} s")
    rendered0 = {n["id"]: n["tiles_rendered"] for n in before["stats"]["nodes"]}
    dropped0 = {n["id"]: n["tiles_dropped"] for n in before["stats"]["nodes"]}
    per_node = [n["tiles_rendered"] - rendered0.get(n["id"], 0) for n in after["stats"]["nodes"]]
    tiles = sum(per_node)
    coordinator_ms = (after["coordinator_cpu_s"] - before["coordinator_cpu_s"]) * 1e3 / frames
    viewer_frames = after["viewer_frames"] - before["viewer_frames"]
    return {
        "seconds": elapsed, "frames": frames, "fps": frames / elapsed, "tiles": tiles, "tiles_per_s": tiles / elapsed,
        "tiles_per_frame": tiles / frames,
        "tiles_per_published_frame": sum(len(n["tiles"]) for n in after["stats"]["nodes"]),
        "node_tiles_min": min(per_node), "node_tiles_max": max(per_node),
        "coordinator_cpu_ms_per_frame": coordinator_ms,
        "receive_cpu_ms_per_frame": (cpu1["receive_ms"] - cpu0["receive_ms"]) / frames,
        "publish_cpu_ms_per_frame": (cpu1["publish_ms"] - cpu0["publish_ms"]) / frames,
        "coordinator_cores": (after["coordinator_cpu_s"] - before["coordinator_cpu_s"]) / elapsed,
        "nodes_cpu_ms_per_frame": (after["nodes_cpu_s"] - before["nodes_cpu_s"]) * 1e3 / frames,
        "nodes_cores": (after["nodes_cpu_s"] - before["nodes_cpu_s"]) / elapsed,
        "ceiling_fps": 1000.0 / coordinator_ms, "ceiling_tiles_per_s": 1000.0 / coordinator_ms * tiles / frames,
        "viewer_fps": viewer_frames / elapsed,
        "viewer_inputs_per_s": (after["viewer_inputs"] - before["viewer_inputs"]) / elapsed,
        "viewer_kb_per_frame": (after["viewer_bytes"] - before["viewer_bytes"]) / max(viewer_frames, 1) / 1e3,
        "frames_cancelled": after["stats"]["frames_cancelled"] - before["stats"]["frames_cancelled"],
        "tiles_dropped": sum(n["tiles_dropped"] - dropped0.get(n["id"], 0) for n in after["stats"]["nodes"]),
        "imbalance_avg": after["stats"]["imbalance_avg"], "latency_ms": after["stats"]["latency_ms"],
        "balancer": after["stats"]["balancer"], "nodes_connected": len(after["stats"]["nodes"]),
        "node_tiles_total_min": min(n["tiles_rendered"] for n in after["stats"]["nodes"]),
    }


async def measure_loopback(url: str, nodes: int, seconds: float, warmup_s: float, coordinator_pid: int,
                           nodes_pid: int) -> dict[str, Any]:
    """Ready, warm up, measure the window, stop the viewer, fetch one composited frame."""
    async with httpx.AsyncClient(base_url=url, timeout=30.0) as http:
        await wait_ready(http, nodes, READY_TIMEOUT_S)
        viewer = ClosedLoopViewer()
        async with connect(url.replace("http://", "ws://", 1) + "/ws/view", max_size=256 << 20,
                           compression=None, proxy=None) as ws:
            task = asyncio.create_task(viewer.run(ws))
            try:
                await asyncio.sleep(warmup_s)
                before = await snapshot(http, viewer, coordinator_pid, nodes_pid)
                await asyncio.sleep(seconds)
                after = await snapshot(http, viewer, coordinator_pid, nodes_pid)
                if task.done():
                    task.result()
                    raise RuntimeError("the viewer's connection ended during the window")
            finally:
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await task
        figures = loopback_figures(before, after)
        response = (await http.get("/api/frame.png", params={"after": after["stats"]["frame"], "timeout": 30})
                    ).raise_for_status()
        image = Image.open(io.BytesIO(response.content))
        figures["frame_png"] = {"frame": int(response.headers["x-frame-id"]), "size": list(image.size),
                                "codec": response.headers["x-tile-codec"], "composite_ms":
                                float(response.headers["x-composite-ms"])}
    return figures


def run_loopback(nodes: int, size: tuple[int, int], seconds: float, warmup_s: float, timeout_s: float) -> dict:
    """One loopback run with ``nodes`` synthetic nodes, within ``timeout_s`` seconds; its figures, the
    synthetic nodes' summaries and the coordinator's log lines."""
    deadline = time.monotonic() + timeout_s
    coordinator, url = start_coordinator(["--size", f"{size[0]}x{size[1]}"], log_level="warning", timeout=timeout_s)
    synthetic: LoggedProcess | None = None
    try:
        synthetic = LoggedProcess([PYTHON, "-m", "bench.synthetic_nodes", "--url", url.replace("http://", "ws://", 1)
                                   + "/ws/node", "--nodes", str(nodes), "--max-seconds", str(timeout_s)])
        try:
            figures = asyncio.run(asyncio.wait_for(
                measure_loopback(url, nodes, seconds, warmup_s, coordinator.process.pid, synthetic.process.pid),
                max(deadline - time.monotonic(), 1.0)))
        except TimeoutError:
            raise TimeoutError(f"the loopback run with {nodes} nodes ran over its {timeout_s:.0f} s; coordinator "
                               "output:\n" + coordinator.output()) from None
    finally:
        if synthetic is not None:
            synthetic.stop()
        coordinator.stop()
    summary = next((json.loads(line) for line in reversed(synthetic.lines) if line.startswith('{"nodes"')), None)
    if summary is None:
        raise RuntimeError("the synthetic nodes printed no summary:\n" + synthetic.output())
    ended = sorted({n["ended"] for n in summary["nodes"]})
    return {"nodes": nodes, **figures, "synthetic_tiles_sent": sum(n["tiles_sent"] for n in summary["nodes"]),
            "synthetic_nodes_ended": ended, "synthetic_log": [line for line in synthetic.lines
                                                              if not line.startswith('{"nodes"')][-50:],
            "coordinator_log": list(coordinator.lines)[-50:]}
