"""Several users on one cluster (issue 19): K sessions, each with its own scene, moved by its own
scripted viewer, on a coordinator with N local nodes.

``python -m bench.sessions --nodes N --sessions K [--scenes builtin:cluster,builtin:spheres]
[--size WxH] [--input-hz 60] [--moving-s 10] [--turn-s 8] [--large-scene NAME] [--idle-s 4]
[--server-args "…"] [--json OUT]``

Phase 1, moving: every viewer (a real ``/ws/view`` client of its session's drive link, as in
:mod:`bench.live`) turns its camera at ``--input-hz``. Per session over the window (its first
second left out): interactive frames received per second (neither the still nor the progressive
still's refinements, which come once the camera rests), input → frame latency p50 in ms and in the
session's own frame intervals, and its ``node_share`` (its fraction of the node time all
sessions' frames took, from ``/api/stats``); Jain's fairness index of the shares; the nodes'
busy fraction (node ms of all frames / (nodes × window)). Phase 2, ``--large-scene`` (a name of
``GET /api/scenes``, e.g. ``library/…`` with ``--server-args '--scenes-dir …'``): a session of it
is opened while the viewers keep moving; the longest gap between frames of any moving session
until it is ready, until a node held it (its parse, not its first frames), and until every node
held it (the nodes load a new scene one after the other). Phase 3, idle:
frames received and the CPU cores the coordinator and its nodes use, from 2 s after the last
input, once every session is settled (its progressive still done), for ``--idle-s`` seconds.

Everything shares this machine's cores: on 2 cores, N nodes are N processes taking turns.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import shlex
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import websockets.sync.client as ws_client

from bench.live import IDLE_AFTER_S, ScriptedViewer, latencies, wait_ready
from bench.processes import cpu_seconds, orbit, process_tree, show_result, start_coordinator
from tessera.cli_values import size_parser


def jain(values: list[float]) -> float:
    """Jain's fairness index of ``values``: 1 when all are equal, 1/n when one has everything."""
    total, squares = sum(values), sum(v * v for v in values)
    return total * total / (len(values) * squares) if squares > 0 else math.nan


def open_session(client: httpx.Client, scene: str, size: tuple[int, int]) -> str:
    response = client.post("/api/sessions", json={"scene": scene, "size": list(size)})
    response.raise_for_status()
    return response.json()["id"]


def wait_session_ready(client: httpx.Client, session_id: str, timeout: float = 600.0,
                       loaded: list[float] | None = None) -> float:
    """Seconds until the session's scene is on a node and a frame of it is out; appended to
    ``loaded``: the seconds until a node reported the scene (its state turned ``ready``)."""
    started = time.perf_counter()
    while time.perf_counter() - started < timeout:
        summary = client.get(f"/api/sessions/{session_id}").json()
        if summary["state"] == "error":
            raise RuntimeError(f"session {session_id[:6]}…: {summary['error']}")
        if summary["state"] == "ready" and loaded is not None and not loaded:
            loaded.append(time.perf_counter() - started)
        if summary["state"] == "ready" and client.get(f"/api/sessions/{session_id}/stats").json()["frame"] > 0:
            return time.perf_counter() - started
        time.sleep(0.05)
    raise RuntimeError(f"session {session_id[:6]}… not ready within {timeout:.0f} s")


def seconds_until(condition: Callable[[], bool], timeout: float, interval: float = 0.1) -> float:
    """Seconds until ``condition()`` holds, asked every ``interval`` s; NaN after ``timeout``."""
    started = time.perf_counter()
    while time.perf_counter() - started < timeout:
        if condition():
            return time.perf_counter() - started
        time.sleep(interval)
    return math.nan


def wait_all_loaded(client: httpx.Client, before: dict[int, int], timeout: float = 300.0) -> float:
    """Seconds until every node holds the new session's scene, once it is ready (``before``: each
    node's ``triangles_loaded`` in ``/api/stats``, by id, before it was opened; the first node
    that reports another count holds the new scene: every node's last scene is that one then;
    none: each had it already); NaN after ``timeout`` (a node that reconnects loads every
    session's scene again)."""
    def everywhere() -> bool:
        nodes = client.get("/api/stats").json()["nodes"]
        loaded = {n["id"]: n["triangles_loaded"] for n in nodes if n["state"] == "ready"}
        changed = [count for node_id, count in loaded.items() if node_id in before and count != before[node_id]]
        return not changed or (len(loaded) == len(nodes) and set(loaded.values()) == {changed[0]})

    return seconds_until(everywhere, timeout)


def wait_settled(client: httpx.Client, ids: list[str], timeout: float = 60.0) -> float:
    """Seconds until every session of ``ids`` is settled (its still done: nothing renders); NaN
    after ``timeout``."""
    return seconds_until(lambda: all(client.get(f"/api/sessions/{i}/stats").json()["settled"] for i in ids), timeout)


def move(viewers: list[ScriptedViewer], until: float, hz: float, turn_s: float, stop: threading.Event) -> None:
    """Every viewer turns its camera at ``hz`` until ``until`` (perf_counter s) or ``stop``."""
    starts = [viewer.camera for viewer in viewers]
    began = next_send = time.perf_counter()
    while (now := time.perf_counter()) < until and not stop.is_set():
        for index, (viewer, camera) in enumerate(zip(viewers, starts, strict=True)):
            viewer.send_camera(orbit(camera, 2.0 * math.pi * (now - began) / turn_s + index))
        next_send += 1.0 / hz
        time.sleep(max(0.0, next_send - time.perf_counter()))


def session_figures(viewer: ScriptedViewer, start: float, end: float) -> dict[str, float]:
    with viewer.lock:
        frames = [f for f in viewer.frames if start <= f["at"] <= end and not (f["still"] or f["samples"])]
        late = [f for f in viewer.frames if start <= f["at"] <= end + 1.0]
    intervals = np.diff([f["at"] for f in frames])
    interval_ms = float(intervals.mean() * 1000.0) if len(intervals) else math.nan
    lat = latencies(late, {k: v for k, v in viewer.sent.items() if start <= v <= end})
    p50 = float(np.percentile(lat, 50)) if lat else math.nan
    return {"fps": len(frames) / (end - start), "frame_interval_ms": interval_ms, "latency_p50_ms": p50,
            "latency_p50_frames": p50 / interval_ms if interval_ms else math.nan,
            "longest_gap_ms": float(intervals.max() * 1000.0) if len(intervals) else math.nan}


def measure(args: argparse.Namespace) -> dict[str, Any]:
    size, scenes = args.size, args.scenes.split(",")
    server_args = ["--local-nodes", str(args.nodes), "--scene", scenes[0], "--size", f"{size[0]}x{size[1]}",
                   "--max-sessions", str(args.sessions + 2), *shlex.split(args.server_args)]
    coordinator, url = start_coordinator(server_args, log_level="warning")
    result: dict[str, Any] = {"nodes": args.nodes, "sessions": args.sessions, "scenes": scenes, "size": list(size),
                              "input_hz": args.input_hz, "server_args": args.server_args}
    try:
        with httpx.Client(base_url=url, timeout=120) as client:
            wait_ready(client, args.nodes)
            ids = ["default"] + [open_session(client, scenes[i % len(scenes)], size) for i in range(1, args.sessions)]
            for session_id in ids:
                wait_session_ready(client, session_id)
            with contextlib.ExitStack() as sockets:
                viewers = [ScriptedViewer(sockets.enter_context(ws_client.connect(
                    url.replace("http://", "ws://") + f"/ws/view?session={session_id}", max_size=256 << 20)))
                    for session_id in ids]
                try:
                    result.update(phases(args, client, ids, viewers, coordinator.process.pid))
                finally:
                    for viewer in viewers:
                        viewer.stop()
    finally:
        coordinator.stop(timeout=30.0)
    return result


def phases(args: argparse.Namespace, client: httpx.Client, ids: list[str], viewers: list[ScriptedViewer],
           coordinator_pid: int) -> dict[str, Any]:
    stop = threading.Event()
    started = time.perf_counter()
    move(viewers, started + args.moving_s, args.input_hz, args.turn_s, stop)
    ended = time.perf_counter()
    stats = client.get("/api/stats").json()
    shares = {s["id"]: s for s in stats["sessions"]}
    per_session = []
    for session_id, viewer in zip(ids, viewers, strict=True):
        figures = session_figures(viewer, started + 1.0, ended)
        per_session.append({"session": shares[session_id]["label"], "scene": shares[session_id]["scene"],
                            "node_share": shares[session_id]["node_share"], **figures})
    busy_ms = sum(s["node_busy_ms"] for s in stats["sessions"])
    out: dict[str, Any] = {"per_session": per_session,
                           "jain_node_share": jain([s["node_share"] for s in per_session]),
                           "node_busy_fraction": busy_ms / (args.nodes * stats["share_window_s"] * 1000.0)}
    opened_ids = list(ids)
    if args.large_scene:
        mover = threading.Thread(target=move, args=(viewers, math.inf, args.input_hz, args.turn_s, stop))
        mover.start()
        time.sleep(1.0)
        before = {n["id"]: n["triangles_loaded"] for n in client.get("/api/stats").json()["nodes"]}
        opened = time.perf_counter()
        loaded: list[float] = []
        try:
            large = open_session(client, args.large_scene, args.size)
            opened_ids.append(large)
            load_s = wait_session_ready(client, large, loaded=loaded)
            everywhere_s = (time.perf_counter() - opened) + wait_all_loaded(client, before)
        finally:
            stop.set()
            mover.join()
        # the frames around the load too: a gap that spans its start or end counts
        gaps = [session_figures(viewer, opened - 0.5, opened + load_s + 0.5)["longest_gap_ms"] for viewer in viewers]
        loading = [session_figures(viewer, opened - 0.5, opened + loaded[0])["longest_gap_ms"] for viewer in viewers]
        everywhere = [session_figures(viewer, opened - 0.5, opened + everywhere_s + 0.5)["longest_gap_ms"]
                      for viewer in viewers] if math.isfinite(everywhere_s) else [math.nan]
        out["large_scene"] = {"name": args.large_scene, "ready_s": load_s, "loaded_s": loaded[0],
                              "longest_gap_ms": max(gaps), "longest_gap_ms_per_session": gaps,
                              "longest_gap_loading_ms": max(loading), "everywhere_s": everywhere_s,
                              "longest_gap_everywhere_ms": max(everywhere)}
    time.sleep(IDLE_AFTER_S)
    out["settled_s"] = IDLE_AFTER_S + wait_settled(client, opened_ids)
    pids = process_tree(coordinator_pid)
    frames_before = sum(len(v.frames) for v in viewers)
    cpu_before, idle_started = cpu_seconds(pids), time.perf_counter()
    time.sleep(args.idle_s)
    wall = time.perf_counter() - idle_started
    out["idle_frames"] = sum(len(v.frames) for v in viewers) - frames_before
    out["idle_cores"] = (cpu_seconds(pids) - cpu_before) / wall
    return out


def report(result: dict[str, Any]) -> str:
    lines = [f"{result['sessions']} sessions on {result['nodes']} local nodes at {result['size'][0]}x"
             f"{result['size'][1]}, viewers moving at {result['input_hz']:g} Hz",
             "session  scene                       fps  latency p50 ms  (frames)  node share  longest gap ms"]
    for s in result["per_session"]:
        lines.append(f"{s['session']:>7}  {s['scene'][:26]:26} {s['fps']:5.1f}  {s['latency_p50_ms']:14.1f}  "
                     f"({s['latency_p50_frames']:5.2f})  {s['node_share']:10.3f}  {s['longest_gap_ms']:14.1f}")
    lines.append(f"Jain's index of the node shares {result['jain_node_share']:.3f}; nodes busy "
                 f"{100 * result['node_busy_fraction']:.0f} % of the time (node ms of all frames / nodes × window)")
    if "large_scene" in result:
        large = result["large_scene"]
        lines.append(f"opening {large['name']}: ready in {large['ready_s']:.1f} s; longest frame gap of the moving "
                     f"sessions meanwhile {large['longest_gap_ms']:.0f} ms; until a node held it "
                     f"({large['loaded_s']:.1f} s) {large['longest_gap_loading_ms']:.0f} ms; until every node held it "
                     f"({large['everywhere_s']:.1f} s) {large['longest_gap_everywhere_ms']:.0f} ms")
    lines.append(f"idle, once every session settled ({result['settled_s']:.1f} s after the last input): "
                 f"{result['idle_frames']} frames, {result['idle_cores']:.3f} cores (coordinator and nodes)")
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m bench.sessions", description=__doc__.split("\n\n")[0])
    parser.add_argument("--nodes", type=int, default=3)
    parser.add_argument("--sessions", type=int, default=4, help="sessions, the default one included")
    parser.add_argument("--scenes", default="builtin:cluster,builtin:spheres",
                        help="comma-separated scene names the sessions take in turn (the first is the default's)")
    parser.add_argument("--size", type=size_parser(16, 8192), default=(320, 180))
    parser.add_argument("--input-hz", type=float, default=60.0)
    parser.add_argument("--moving-s", type=float, default=10.0)
    parser.add_argument("--turn-s", type=float, default=8.0)
    parser.add_argument("--large-scene", help="a scene name to open while the others move (phase 2)")
    parser.add_argument("--idle-s", type=float, default=4.0)
    parser.add_argument("--server-args", default="", help="more flags for python -m server")
    parser.add_argument("--json", type=Path)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.sessions < 1 or args.nodes < 1 or args.moving_s <= 1.0:
        raise SystemExit("--sessions and --nodes must be >= 1, --moving-s > 1")
    result = measure(args)
    show_result(report(result), result, args.json, argv)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
