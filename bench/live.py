"""The live service as a new user meets it: the coordinator with N local nodes and every default,
one scripted viewer turning the camera at 60 Hz, then letting go.

``python -m bench.live --nodes N [--scene S] [--size WxH] [--moving-s 8] [--idle-s 4]
[--server-args "…"] [--json OUT]``

The viewer is a real WebSocket client of ``/ws/view``: it sends camera messages with input
sequence numbers at ``--input-hz`` while the camera orbits (a turn every ``--turn-s`` seconds),
and reads the frames as they come off the socket. Figures:

* fps while moving: frames received per second over the moving window (its first second left out);
* latency: input → frame on the viewer socket, for the first frame answering each input (the
  frame header carries the viewer's input number), p50 and p90 in ms and in frame intervals (the
  mean interval between frames while moving);
* KB per interactive frame, and the still frame: its delay after the last input, its KB, and its
  PSNR and share of pixels off by more than 8 levels against ``python -m node --render-once`` of
  the last camera (with ``--rests``, the last rest's still); ``refinements``: when each
  progressive still frame came after the last input (its sample count, ms);
* ``--rests N``: N − 1 more rests after the idle window, each after ``--rest-moving-s`` of motion:
  ``still_after_ms_rests`` the still's delay after the last input of every rest (the first one's
  included), their median ``still_after_ms_median``;
* idle: frames received and the CPU cores used by the coordinator and its nodes (``/proc``),
  from 2 s after the last input for ``--idle-s`` seconds;
* the coordinator's own figures from ``/api/stats`` (imbalance_avg, latency_ms, frames cancelled),
  and its decomposition mode with the CPU it spent merging by depth per frame published while
  moving (``merge_ms_per_frame``: 0 in sort-first; ``--server-args '--mode hybrid'``).

Everything shares this machine's cores; ``--server-args`` passes flags to ``python -m server``
(e.g. ``--max-in-flight 1``) to compare settings against the defaults.
"""

from __future__ import annotations

import argparse
import io
import json
import math
import shlex
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import websockets.sync.client as ws_client
from PIL import Image

from bench.images import psnr, viewer_frame_image
from bench.processes import REPO, cpu_seconds, orbit, process_tree, show_result, start_coordinator
from tessera.cli_values import size_parser
from tessera.wire.messages import CameraUpdate
from tessera.wire.protocol import unpack_frame

IDLE_AFTER_S = 2.0
#: How long a rest of ``--rests`` waits for its still at most, s.
REST_TIMEOUT_S = 10.0


class ScriptedViewer:
    """A viewer on an open ``/ws/view`` connection: a reader thread records every frame (receive
    time, id, bytes, still flag, input number); :meth:`send_camera` sends a camera with the next
    input number."""

    def __init__(self, ws: ws_client.ClientConnection) -> None:
        self.ws = ws
        hello = json.loads(self.ws.recv(timeout=30))
        assert hello["type"] == "hello", hello
        self.camera: dict[str, Any] = hello["camera"]
        self.frames: list[dict[str, Any]] = []
        self.sent: dict[int, float] = {}
        self.seq = 0
        self.lock = threading.Lock()
        self._stop = threading.Event()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        while not self._stop.is_set():
            try:
                message = self.ws.recv(timeout=0.2)
            except TimeoutError:
                continue
            except Exception:
                return
            if isinstance(message, bytes):
                now = time.perf_counter()
                frame = unpack_frame(message)
                with self.lock:
                    self.frames.append({"at": now, "id": frame.frame_id, "bytes": len(message), "still": frame.still,
                                        "input": frame.input_seq, "samples": frame.samples,
                                        "message": message if frame.still else None})

    def send_camera(self, camera: dict[str, Any]) -> None:
        self.seq += 1
        self.sent[self.seq] = time.perf_counter()
        self.camera = camera
        self.ws.send(CameraUpdate(camera=camera, seq=self.seq).to_text())

    def wait_for_still(self, after: float, timeout: float) -> None:
        """Until a still frame came after ``after`` (perf_counter s), at most ``timeout`` s."""
        deadline = time.perf_counter() + timeout
        while time.perf_counter() < deadline:
            with self.lock:
                if any(f["still"] and f["at"] > after for f in self.frames):
                    return
            time.sleep(0.02)

    def stop(self) -> None:
        self._stop.set()
        self._reader.join(timeout=5)


def latencies(frames: list[dict[str, Any]], sent: dict[int, float]) -> list[float]:
    """ms from each input to the first frame that answers it (a frame answers every input ≤ its number)."""
    out, answered = [], 0
    for frame in frames:
        if frame["input"] > answered and frame["input"] in sent:
            out.append((frame["at"] - sent[frame["input"]]) * 1000.0)
            answered = frame["input"]
    return out


def render_once(scene: str, camera: dict[str, Any], size: tuple[int, int], *flags: str) -> np.ndarray:
    """``python -m node --render-once`` of ``camera`` with ``flags`` (default: the still the
    coordinator converges to with its defaults); (h, w, 3) uint8."""
    with tempfile.TemporaryDirectory() as tmp:
        camera_file, out = Path(tmp) / "camera.json", Path(tmp) / "reference.png"
        camera_file.write_text(json.dumps(camera))
        subprocess.run([sys.executable, "-m", "node", "--render-once", str(out), "--scene", scene, "--camera",
                        str(camera_file), "--size", f"{size[0]}x{size[1]}", *flags], cwd=REPO, check=True,
                       capture_output=True, timeout=300)
        return np.asarray(Image.open(io.BytesIO(out.read_bytes())).convert("RGB"))


def wait_ready(client: httpx.Client, nodes: int, timeout: float = 300.0) -> dict[str, Any]:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        stats = client.get("/api/stats").json()
        if sum(n["state"] == "ready" for n in stats["nodes"]) == nodes and stats["frame"] > 0 and stats["settled"]:
            calibrated = all(n["calibration_ms"] for n in stats["nodes"])
            if calibrated:
                return stats
        time.sleep(0.2)
    raise RuntimeError(f"{nodes} nodes not ready and calibrated within {timeout} s")


@dataclass
class Run:
    """What one drive of the service recorded: perf_counter times (s) of the start and the last
    input, coordinator stats at 1 s, at the last input and at the end, and the idle window's
    frames, CPU seconds and length."""

    started: float
    last_input: float
    stats_before: dict[str, Any]
    stats_moving: dict[str, Any]
    stats_idle: dict[str, Any]
    idle_frames: int
    idle_cpu_s: float
    idle_wall_s: float
    rests: list[float]


def drive(args: argparse.Namespace, client: httpx.Client, viewer: ScriptedViewer, coordinator_pid: int) -> Run:
    """Turn the camera at ``--input-hz`` for ``--moving-s``, let go, measure the idle window; then
    the ``--rests`` that follow."""
    start_camera = viewer.camera
    started = next_send = time.perf_counter()
    pauses = np.random.default_rng(0)
    next_pause = started + args.pause_every_s
    stats_before: dict[str, Any] | None = None
    while (now := time.perf_counter()) < started + args.moving_s:
        if stats_before is None and now >= started + 1.0:
            stats_before = client.get("/api/stats").json()
        if args.pause_ms and now >= next_pause:
            time.sleep(pauses.uniform(*args.pause_ms) / 1000.0)
            next_pause = next_send = time.perf_counter()
            next_pause += args.pause_every_s
            continue
        viewer.send_camera(orbit(start_camera, 2.0 * math.pi * (now - started) / args.turn_s))
        next_send += 1.0 / args.input_hz
        time.sleep(max(0.0, next_send - time.perf_counter()))
    last_input = time.perf_counter()
    stats_moving = client.get("/api/stats").json()
    time.sleep(IDLE_AFTER_S)
    pids = process_tree(coordinator_pid)
    cpu_before, idle_started, frames_before = cpu_seconds(pids), time.perf_counter(), len(viewer.frames)
    time.sleep(args.idle_s)
    idle_cpu = cpu_seconds(pids) - cpu_before
    idle_wall = time.perf_counter() - idle_started
    idle_frames = len(viewer.frames) - frames_before
    assert stats_before is not None, "--moving-s must exceed 1 s"
    stats_idle = client.get("/api/stats").json()
    rests = [last_input]
    for rest in range(1, args.rests):
        moving_from = next_send = time.perf_counter()
        while (now := time.perf_counter()) < moving_from + args.rest_moving_s:
            viewer.send_camera(orbit(start_camera, 2.0 * math.pi * (args.moving_s + rest + now - moving_from)
                                     / args.turn_s))
            next_send += 1.0 / args.input_hz
            time.sleep(max(0.0, next_send - time.perf_counter()))
        rests.append(time.perf_counter())
        viewer.wait_for_still(rests[-1], REST_TIMEOUT_S)
    return Run(started, last_input, stats_before, stats_moving, stats_idle, idle_frames, idle_cpu, idle_wall, rests)


def measure(args: argparse.Namespace) -> dict[str, Any]:
    size = args.size
    server_args = ["--local-nodes", str(args.nodes), "--scene", args.scene, "--size", f"{size[0]}x{size[1]}",
                   *shlex.split(args.server_args)]
    coordinator, url = start_coordinator(server_args, log_level="warning")
    try:
        with httpx.Client(base_url=url, timeout=120) as client:
            wait_ready(client, args.nodes)
            if args.balancer_params:
                name = client.get("/api/balancer").json()["name"]
                client.put("/api/balancer", json={"name": name, "params": json.loads(args.balancer_params)}) \
                    .raise_for_status()
            with ws_client.connect(url.replace("http://", "ws://") + "/ws/view", max_size=256 << 20) as ws:
                viewer = ScriptedViewer(ws)
                run = drive(args, client, viewer, coordinator.process.pid)
                viewer.stop()
    finally:
        coordinator.stop(timeout=30.0)
    return figures(args, viewer, run)


def figures(args: argparse.Namespace, viewer: ScriptedViewer, run: Run) -> dict[str, Any]:
    """The benchmark's figures from the frames the viewer received and the coordinator's stats."""
    with viewer.lock:
        frames = list(viewer.frames)
    window_start = run.started + 1.0
    window = [f for f in frames if window_start <= f["at"] <= run.last_input and not f["still"]]
    moving_s = run.last_input - window_start
    intervals = np.diff([f["at"] for f in window])
    interval_ms = float(intervals.mean() * 1000.0) if len(intervals) else math.nan
    lat = np.array(latencies([f for f in frames if window_start <= f["at"] <= run.last_input + 1.0],
                             {k: v for k, v in viewer.sent.items() if v >= window_start}))
    stills = [f for f in frames if f["still"] and f["at"] > run.rests[-1]]   # of the camera sent last
    stills_moving = sum(f["still"] for f in frames if window_start <= f["at"] <= run.last_input)
    moving, before = run.stats_moving, run.stats_before
    published = moving["coordinator_cpu"]["frames"] - before["coordinator_cpu"]["frames"]
    merged_ms = moving["coordinator_cpu"].get("merge_ms", 0.0) - before["coordinator_cpu"].get("merge_ms", 0.0)
    result: dict[str, Any] = {
        "nodes": args.nodes, "scene": args.scene, "size": list(args.size), "server_args": args.server_args,
        "balancer_params": moving["balancer_params"],
        "balancer": moving["balancer"], "renderer": moving["nodes"][0]["renderer"],
        "mode": moving.get("mode", "sort-first"),
        "merge_ms_per_frame": merged_ms / published if published else math.nan,
        "fps_moving": len(window) / moving_s,
        "published_fps_moving": published / moving_s,
        "frame_interval_ms": interval_ms,
        "latency_p50_ms": float(np.percentile(lat, 50)) if len(lat) else math.nan,
        "latency_p90_ms": float(np.percentile(lat, 90)) if len(lat) else math.nan,
        "latency_samples": len(lat),
        "kb_interactive": float(np.mean([f["bytes"] for f in window]) / 1024.0) if window else math.nan,
        "idle_fps": run.idle_frames / run.idle_wall_s,
        "idle_cores": run.idle_cpu_s / run.idle_wall_s,
        "imbalance_avg": moving["imbalance_avg"],
        "coordinator_latency_ms": moving["latency_ms"],
        "frames_cancelled": run.stats_idle["frames_cancelled"],
        "stills_while_moving": stills_moving,
        "frames_published": run.stats_idle["coordinator_cpu"]["frames"],
    }
    result["latency_p50_frames"] = result["latency_p50_ms"] / interval_ms
    result["latency_p90_frames"] = result["latency_p90_ms"] / interval_ms
    result.update(still_kb=math.nan, still_after_ms=math.nan, still_identical=False, still_psnr_db=math.nan,
                  still_pixels_off=math.nan)
    first_rest_end = run.rests[1] if len(run.rests) > 1 else math.inf
    result["refinements"] = [[f["samples"], (f["at"] - run.last_input) * 1000.0] for f in frames
                             if run.last_input < f["at"] < first_rest_end and (f["samples"] or f["still"])]
    result["still_after_ms_rests"] = [next(((f["at"] - rest) * 1000.0 for f in frames if f["still"] and f["at"] > rest),
                                           math.nan) for rest in run.rests]
    result["still_after_ms_median"] = float(np.median(result["still_after_ms_rests"]))
    if stills:
        still = stills[0]
        image = viewer_frame_image(still["message"])
        reference = render_once(args.scene, viewer.camera, args.size)
        off = np.abs(image.astype(np.int16) - reference.astype(np.int16)).max(axis=2) > 8
        quality = psnr(image, reference)
        result.update(still_kb=still["bytes"] / 1024.0, still_after_ms=result["still_after_ms_rests"][0],
                      still_identical=quality == math.inf, still_psnr_db=None if quality == math.inf else quality,
                      still_pixels_off=float(off.mean()))
    return result


def report(result: dict[str, Any]) -> str:
    psnr_text = "identical" if result["still_identical"] else f"PSNR {result['still_psnr_db']:.1f} dB"
    return "\n".join([
        f"Tessera live benchmark: {result['nodes']} local nodes, {result['scene']} at "
        f"{result['size'][0]}x{result['size'][1]}, balancer {result['balancer']}"
        + (f", server args {result['server_args']!r}" if result["server_args"] else ", every default"),
        f"  renderer        {result['renderer']}",
        f"  moving          {result['fps_moving']:.1f} fps on the viewer socket "
        f"(published {result['published_fps_moving']:.1f}), frame interval {result['frame_interval_ms']:.1f} ms",
        f"  latency         p50 {result['latency_p50_ms']:.1f} ms = {result['latency_p50_frames']:.2f} frames, "
        f"p90 {result['latency_p90_ms']:.1f} ms = {result['latency_p90_frames']:.2f} frames "
        f"({result['latency_samples']} inputs answered); "
        f"coordinator input→publish {result['coordinator_latency_ms']:.1f} ms",
        f"  mode            {result['mode']}: merging by depth {result['merge_ms_per_frame']:.2f} ms of coordinator "
        "CPU per frame published while moving",
        f"  imbalance_avg   {result['imbalance_avg']:.3f}; frames cancelled {result['frames_cancelled']}; "
        f"still frames shown while moving {result['stills_while_moving']}",
        f"  frames          {result['kb_interactive']:.1f} KB interactive; still {result['still_kb']:.1f} KB, "
        f"{result['still_after_ms']:.0f} ms after the last input",
        f"  still vs render-once  {psnr_text}, {result['still_pixels_off']:.4%} of pixels off by > 8",
        "  refinements     " + (" ".join(f"{samples}@{ms:.0f}" for samples, ms in result["refinements"]) or "none")
        + " (samples@ms after the last input)",
        f"  rest -> still   median {result['still_after_ms_median']:.0f} ms over {len(result['still_after_ms_rests'])} "
        f"rests ({', '.join(f'{ms:.0f}' for ms in result['still_after_ms_rests'])})",
        f"  idle            {result['idle_fps']:.2f} fps, {result['idle_cores']:.3f} cores (coordinator + nodes), "
        f"from {IDLE_AFTER_S:.0f} s after the last input",
    ])


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m bench.live", description=__doc__.split("\n\n")[0])
    parser.add_argument("--nodes", type=int, default=3)
    parser.add_argument("--scene", default="builtin:cluster")
    parser.add_argument("--size", type=size_parser(16, 8192), default=(1280, 720))
    parser.add_argument("--moving-s", type=float, default=8.0, help="seconds of camera motion (default 8)")
    parser.add_argument("--idle-s", type=float, default=4.0, help="seconds measured idle (default 4)")
    parser.add_argument("--input-hz", type=float, default=60.0, help="camera messages per second (default 60)")
    parser.add_argument("--turn-s", type=float, default=8.0, help="seconds per turn of the orbit (default 8)")
    parser.add_argument("--server-args", default="", help="extra flags for python -m server, e.g. '--max-in-flight 1'")
    parser.add_argument("--pause-ms", type=lambda t: tuple(float(v) for v in t.split(",")),
                        help="LO,HI: a hand that stops: every --pause-every-s, no input for a random LO…HI ms "
                             "(seeded; skews fps and latency, for the still frame's quiet period)")
    parser.add_argument("--pause-every-s", type=float, default=1.0)
    parser.add_argument("--rests", type=int, default=1,
                        help="rests measured: the first after --moving-s, each other after --rest-moving-s (default 1)")
    parser.add_argument("--rest-moving-s", type=float, default=1.0,
                        help="seconds of camera motion before each rest after the first (default 1)")
    parser.add_argument("--balancer-params", default="",
                        help='JSON parameters for the balancer, set with PUT /api/balancer, e.g. \'{"tau_ms": 100}\'')
    parser.add_argument("--json", type=Path, help="write the figures here")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    result = measure(args)
    show_result(report(result), result, args.json, argv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
