"""End-to-end frame rate and coordinator cost.

``python -m bench.frame_rate [--nodes 3] [--sizes 1280x720,1920x1080] [--seconds 15] [--scene S]
[--codec jpeg] [--json OUT]``

For each size: starts ``python -m server --local-nodes N``, connects one real viewer over
``/ws/view`` that turns the camera at 60 Hz (frames render only while something changes), lets it
warm up, then measures over a window: published frames/s, frames/s the
viewer received, the coordinator's CPU milliseconds per frame spent receiving tiles and publishing
frames (thread CPU time around those handlers) and its whole-process CPU per frame, the CPU cost of
one on-demand composite (decode + paste, from ``GET /api/frame.png``'s ``X-Composite-Ms``), and
bytes per frame to the viewer. Nodes and coordinator share this machine's cores.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import threading
import time
from pathlib import Path

import httpx
import websockets.sync.client as ws_client

from bench.processes import orbit, start_coordinator
from tessera.wire.messages import CameraUpdate

INPUT_HZ = 60.0
TURN_S = 8.0


class ViewerCounter:
    """A real viewer connection that turns the camera at :data:`INPUT_HZ` (a turn in
    :data:`TURN_S` s) and counts the frames and bytes it receives."""

    def __init__(self, url: str) -> None:
        self.frames = 0
        self.bytes = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(url,), daemon=True)
        self._thread.start()

    def _run(self, url: str) -> None:
        with ws_client.connect(url, max_size=256 << 20) as ws:
            camera = json.loads(ws.recv(timeout=30))["camera"]
            started = next_input = time.monotonic()
            while not self._stop.is_set():
                now = time.monotonic()
                if now >= next_input:
                    turned = orbit(camera, 2.0 * math.pi * (now - started) / TURN_S)
                    ws.send(CameraUpdate(camera=turned).to_text())
                    next_input += 1.0 / INPUT_HZ
                try:
                    message = ws.recv(timeout=max(next_input - time.monotonic(), 0.0))
                except TimeoutError:
                    continue
                if isinstance(message, bytes):
                    self.frames += 1
                    self.bytes += len(message)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)


def wait_ready(client: httpx.Client, nodes: int, timeout: float = 180.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        stats = client.get("/api/stats").json()
        if sum(n["state"] == "ready" for n in stats["nodes"]) == nodes and stats["frame"] > 0:
            return
        time.sleep(0.2)
    raise RuntimeError(f"{nodes} nodes not ready within {timeout} s")


def measure(size: str, nodes: int, seconds: float, scene: str, codec: str) -> dict:
    coordinator, url = start_coordinator(["--local-nodes", str(nodes), "--size", size, "--scene", scene,
                                          "--codec", codec], log_level="warning")
    try:
        with httpx.Client(base_url=url, timeout=120) as client:
            wait_ready(client, nodes)
            viewer = ViewerCounter(url.replace("http://", "ws://") + "/ws/view")
            time.sleep(min(3.0, seconds / 3))
            before, viewer_before, t0 = client.get("/api/stats").json(), (viewer.frames, viewer.bytes), time.monotonic()
            time.sleep(seconds)
            after, viewer_after, t1 = client.get("/api/stats").json(), (viewer.frames, viewer.bytes), time.monotonic()
            viewer.stop()
            composites = []
            for _ in range(3):
                response = client.get("/api/frame.png", params={"after": after["frame"]})
                composites.append(float(response.headers["x-composite-ms"]))
            cpu0, cpu1 = before["coordinator_cpu"], after["coordinator_cpu"]
            frames = max(cpu1["frames"] - cpu0["frames"], 1)
            viewer_frames = max(viewer_after[0] - viewer_before[0], 1)
            return {
                "size": size, "nodes": nodes, "scene": scene, "codec": codec,
                "fps": round((cpu1["frames"] - cpu0["frames"]) / (t1 - t0), 2),
                "viewer_fps": round((viewer_after[0] - viewer_before[0]) / (t1 - t0), 2),
                "receive_cpu_ms_per_frame": round((cpu1["receive_ms"] - cpu0["receive_ms"]) / frames, 3),
                "publish_cpu_ms_per_frame": round((cpu1["publish_ms"] - cpu0["publish_ms"]) / frames, 3),
                "composite_cpu_ms_per_frame": 0.0,
                "process_cpu_ms_per_frame": round((cpu1["process_ms"] - cpu0["process_ms"]) / frames, 3),
                "on_demand_composite_ms": round(min(composites), 3),
                "viewer_bytes_per_frame": round((viewer_after[1] - viewer_before[1]) / viewer_frames),
                "imbalance_avg": after["imbalance_avg"],
                "latency_ms": after["latency_ms"],
                "renderer": after["nodes"][0]["renderer"] if after["nodes"] else "",
            }
    finally:
        coordinator.stop(timeout=20.0)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.frame_rate", description=__doc__.split("\n\n")[0])
    parser.add_argument("--nodes", type=int, default=3)
    parser.add_argument("--sizes", default="1280x720,1920x1080")
    parser.add_argument("--seconds", type=float, default=15.0)
    parser.add_argument("--scene", default="builtin:cluster")
    parser.add_argument("--codec", default="jpeg", choices=["jpeg", "png", "raw"])
    parser.add_argument("--json", type=Path, help="write the results here")
    args = parser.parse_args(argv)
    results = [measure(size, args.nodes, args.seconds, args.scene, args.codec) for size in args.sizes.split(",")]
    columns = ["size", "fps", "viewer_fps", "receive_cpu_ms_per_frame", "publish_cpu_ms_per_frame",
               "composite_cpu_ms_per_frame", "process_cpu_ms_per_frame", "on_demand_composite_ms",
               "viewer_bytes_per_frame", "imbalance_avg", "latency_ms"]
    print(f"{args.nodes} local nodes, scene {args.scene}, codec {args.codec}, "
          f"renderer {results[0]['renderer'] if results else '?'}")
    print("  ".join(f"{c:>12}" for c in ["size", "fps", "viewer fps", "recv ms/f", "publish ms/f",
                                          "composite ms/f", "process ms/f", "on-demand ms", "bytes/frame",
                                          "imbalance", "latency ms"]))
    for row in results:
        print("  ".join(f"{row[c]!s:>12}" for c in columns))
    print("Coordinator CPU per frame: receive + publish are thread CPU time in those handlers; the live loop "
          "forwards the nodes' encoded tiles to viewers without decoding (composite 0); 'on-demand' is the cost "
          "of one full decode+paste for GET /api/frame.png; 'process' is the whole coordinator process.")
    if args.json:
        args.json.write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
