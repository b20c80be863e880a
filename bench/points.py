"""Point clouds as a user opens and moves them (issue 36): ingest, first frame, the picture moving
within a point budget, and the moving frame against the still.

``python -m bench.points (--terrain N | --scan-copies K | --cloud PATH) [--nodes 3] [--size 1280x720]
[--budgets 500000,1000000] [--paths oblique,overhead,ground,close] [--moving-s 8] [--input-hz 30]
[--work DIR] [--json OUT]``

The cloud: ``--terrain N``, a synthetic terrain of N points in survey coordinates (UTM eastings of
5·10⁵ m, northings of 4·10⁶ m; a 0.25 m grid jittered by 2 cm, scan-line order, height and RGB),
written as LAZ (point format 3, millimetre scale) into ``--work``; ``--scan-copies K``, the Pan
scan's vertices (no faces: a point cloud), K×K copies on a grid as one binary PLY; ``--cloud``, a
file of your own. Then, in a fresh scene cache folder:

- ``ingest``: the cache built in a child process (read, octree, written, checked): points/s by the
  wall clock, the CPU seconds it used (both cores count), the seconds the read alone took, its peak
  resident memory;
- ``first_frame_s``: a coordinator with ``--local-nodes N`` (the cache kept) and a session opened on
  the cloud: seconds from ``POST /api/sessions`` to its first frame;
- for each budget of ``--budgets`` (the coordinator's ``--point-budget``, where its loop starts; with
  ``--fixed-budget`` the budget of every frame), along each camera path of
  ``--paths`` (:data:`PATHS`: oblique, overhead, near the ground looking across, close to the
  middle), a scripted viewer orbits the camera at ``--input-hz`` for ``--moving-s`` at ``--size``:
  frames per second, input → frame latency, the points the busiest node drew per frame, the nodes'
  busy time, the point budget the session's loop used (``budget_in_use``: least, median, most), and
  the seconds from its first input to the first frame that answers one
  (``first_answer_s``: right after the first frame, on the warm-up, a still's samples under way);
  ``--rests`` times, the camera rests for ``--rest-s`` (a still begins) and moves again:
  ``resume_s``, the seconds from the first input after the rest to the first frame that answers
  one; then one camera's moving frame against the still of the same camera (PSNR), the
  still's seconds and its samples; with ``--every-point-s``, the still of every point that follows
  it where it left points out (seconds after the first still, samples, PSNR of the moving frame
  and of the first still against it; ``--save DIR``: its PNG and camera, for ``--render-once``);
  and the peak memory of the coordinator and its nodes together (PSS: the pages they share, the
  mapped cache, counted once; their RSS summed; and each process's peak RSS).

Figures depend on what else runs: the table prints the load average beside them.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import os
import resource
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import websockets.sync.client as ws_client
from PIL import Image

from bench.big_models import grid_offsets
from bench.images import psnr
from bench.live import ScriptedViewer
from bench.processes import PYTHON, REPO, cpu_seconds, process_tree, show_result, start_coordinator
from bench.sessions import open_session, session_figures, wait_session_ready
from tessera.cli_values import parse_point_budget, size_parser

#: Points written to a LAZ file at a time.
WRITE_CHUNK = 5_000_000
DEFAULT_SCAN = REPO.parent / "shared" / "scenes" / "large_scan" / "threedscans_pan_990k.ply"
#: Seconds a viewer that moved again after a rest waits at most for the first frame that answers.
RESUME_WAIT_S = 120.0


def terrain_chunk(first: int, count: int, side: int, seed: int) -> np.ndarray:
    """(count, 3) float64 terrain points ``first`` … ``first + count`` of a ``side``-wide grid."""
    rng = np.random.default_rng(seed + first)
    index = np.arange(first, first + count)
    x = (index % side) * 0.25 + rng.normal(0.0, 0.02, count)
    y = (index // side) * 0.25 + rng.normal(0.0, 0.02, count)
    z = 100.0 + 25.0 * np.sin(x / 90.0) * np.cos(y / 130.0) + 3.0 * np.sin(x / 7.0 + y / 11.0)
    return np.stack([x + 500000.0, y + 4000000.0, z], axis=1)


def write_terrain(path: Path, count: int, seed: int = 7) -> Path:
    """A LAZ terrain of ``count`` points (module docstring), written a chunk at a time."""
    import laspy

    header = laspy.LasHeader(point_format=3, version="1.2")
    header.offsets, header.scales = [500000.0, 4000000.0, 0.0], [0.001, 0.001, 0.001]
    side = int(math.sqrt(count)) + 1
    partial = path.with_suffix(".partial.laz")
    with laspy.open(str(partial), mode="w", header=header, laz_backend=laspy.LazBackend.LazrsParallel) as writer:
        for first in range(0, count, WRITE_CHUNK):
            xyz = terrain_chunk(first, min(WRITE_CHUNK, count - first), side, seed)
            points = laspy.ScaleAwarePointRecord.zeros(len(xyz), header=header)
            points.x, points.y, points.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
            shade = (xyz[:, 2] - 70.0) / 60.0
            points.red = np.clip(shade * 60000, 0, 65535).astype(np.uint16)
            points.green = np.clip((1.0 - np.abs(shade - 0.5)) * 60000, 0, 65535).astype(np.uint16)
            points.blue = np.clip((1.0 - shade) * 50000, 0, 65535).astype(np.uint16)
            points.intensity = np.clip(shade * 4000, 0, 65535).astype(np.uint16)
            writer.write_points(points)
    partial.rename(path)
    return path


def write_scan_points(path: Path, scan: Path, copies: int) -> Path:
    """The vertices of the PLY ``scan``, ``copies`` × ``copies`` copies on a grid, as a binary PLY of
    vertices without faces (a point cloud)."""
    from node.scene.ply import read_ply_arrays

    vertices, _ = read_ply_arrays(scan)
    offsets = grid_offsets(vertices.min(axis=0), vertices.max(axis=0), copies)
    count = len(vertices) * len(offsets)
    partial = path.with_suffix(".partial.ply")
    with partial.open("wb") as file:
        file.write(f"ply\nformat binary_little_endian 1.0\nelement vertex {count}\nproperty float x\n"
                   "property float y\nproperty float z\nend_header\n".encode())
        for offset in offsets:
            file.write((vertices + offset).astype("<f4").tobytes())
    partial.rename(path)
    return path


INGEST = r"""
import json, resource, sys, time
from pathlib import Path
started, cpu = time.perf_counter(), time.process_time()
from node.scene.cache_folder import CacheFolder
from node.scene.point_cache import cached_points, open_points_entry
stages = {}
def progress(fraction, message):
    stages.setdefault(round(fraction, 2), time.perf_counter() - started)
entry = cached_points(Path(sys.argv[1]), None, CacheFolder(Path(sys.argv[2]), 1 << 50), progress)
cloud = open_points_entry(entry, "cloud", verify=False)
print(json.dumps({"points": cloud.point_count, "nodes": cloud.nodes.count, "wall_s": time.perf_counter() - started,
                  "cpu_s": time.process_time() - cpu, "read_s": stages.get(0.3), "peak_mb":
                  resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def ingest(cloud: Path, cache: Path) -> dict[str, Any]:
    """The cache of ``cloud`` built in a child process (niced as a node's reader is)."""
    out = subprocess.run(["nice", "-n", "10", PYTHON, "-c", INGEST, str(cloud), str(cache)], cwd=REPO,
                         capture_output=True, text=True, check=True)
    figures = json.loads(out.stdout.strip().splitlines()[-1])
    figures["built"] = figures["read_s"] is not None     # else the cache held an entry: hashed and opened only
    figures["points_per_s"] = figures["points"] / figures["wall_s"] if figures["built"] else None
    figures["points_per_cpu_s"] = figures["points"] / figures["cpu_s"] if figures["built"] else None
    return {key: round(value, 2) if isinstance(value, float) else value for key, value in figures.items()}


#: The camera paths a viewer moves along (``--paths``): elevation above the cloud's middle (degrees)
#: and distance (fractions of its diagonal); each orbits the middle, a turn in 16 s.
PATHS = {"oblique": (30.0, 0.45), "overhead": (75.0, 0.6), "ground": (4.0, 0.5), "close": (25.0, 0.06)}


def oblique(bounds: list[list[float]], angle: float, path: str = "oblique") -> dict[str, Any]:
    """A camera of ``path`` (:data:`PATHS`; default 30° above the cloud's middle, 0.45 of its
    diagonal away) turned ``angle`` radians about the vertical (z, or y for a cloud taller than deep)."""
    elevation, reach = PATHS[path]
    lo, hi = np.asarray(bounds, float)
    centre, extent = (lo + hi) / 2.0, hi - lo
    up = 2 if extent[2] < extent[1] else 1
    across = [axis for axis in range(3) if axis != up]
    distance = float(np.linalg.norm(extent)) * reach
    eye = centre.copy()
    eye[across[0]] += distance * math.cos(angle) * math.cos(math.radians(elevation))
    eye[across[1]] += distance * math.sin(angle) * math.cos(math.radians(elevation))
    eye[up] = max(eye[up] + distance * math.sin(math.radians(elevation)), hi[up] + 0.01 * distance)
    direction = [0.0, 0.0, 0.0]
    direction[up] = 1.0
    return {"eye": eye.tolist(), "target": centre.tolist(), "up": direction, "fovy_deg": 50.0}


def tree_memory(pid: int) -> tuple[float, float, dict[int, float]]:
    """(PSS, RSS, {member: RSS}) MB of process ``pid`` and its descendants (PSS: shared pages counted
    once over all)."""
    pss = rss = 0
    each: dict[int, float] = {}
    for member in process_tree(pid):
        try:
            with open(f"/proc/{member}/smaps_rollup") as rollup:
                for line in rollup:
                    if line.startswith(("Pss:", "Rss:")):
                        kb = int(line.split()[1])
                        pss, rss = (pss + kb, rss) if line.startswith("Pss:") else (pss, rss + kb)
                        if line.startswith("Rss:"):
                            each[member] = kb / 1024.0
        except (OSError, ValueError):
            continue
    return pss / 1024.0, rss / 1024.0, each


class MemoryPeak:
    """The peak PSS and RSS of a process tree, and each member's peak RSS, sampled every ``every`` s
    on a thread until :meth:`stop`."""

    def __init__(self, pid: int, every: float = 0.5) -> None:
        self.pid, self.every = pid, every
        self.pss_mb = self.rss_mb = 0.0
        self.each_mb: dict[int, float] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)
        self._thread.start()

    def _sample(self) -> None:
        while True:
            pss, rss, each = tree_memory(self.pid)
            self.pss_mb, self.rss_mb = max(self.pss_mb, pss), max(self.rss_mb, rss)
            for member, mb in each.items():
                self.each_mb[member] = max(self.each_mb.get(member, 0.0), mb)
            if self._stop.wait(self.every):
                return

    def stop(self) -> dict[str, float]:
        self._stop.set()
        self._thread.join()
        return {"peak_pss_mb": round(self.pss_mb), "peak_rss_mb": round(self.rss_mb),
                "peak_rss_each_mb": sorted((round(mb) for mb in self.each_mb.values()), reverse=True)}


def start(args: argparse.Namespace, cloud: Path, cache: Path, budget: int) -> tuple[Any, str]:
    flags = ["--local-nodes", str(args.nodes), "--scenes-dir", str(cloud.parent), "--frame-wait-s", "600",
             "--size", f"{args.size[0]}x{args.size[1]}", "--point-budget", str(budget),
             *(["--point-budget-min", str(budget), "--point-budget-max", str(budget)] if args.fixed_budget else []),
             "--session-idle-timeout-s", "86400"]    # a still of every point may take longer than the default
    return start_coordinator(flags, log_level="warning", timeout=120,
                             env={"TESSERA_SCENE_CACHE_DIR": str(cache), "TESSERA_SCENE_MEMORY_MB": "20000"})


def move(client: httpx.Client, viewer: ScriptedViewer, session: str, bounds: list[list[float]], path: str,
         seconds: float, args: argparse.Namespace, pid: int) -> dict[str, Any]:
    """``viewer`` moving the camera along ``path`` for ``seconds``: its figures, the points the
    busiest node drew and its busy time (medians over the samples of the stats), the point budget
    the session's loop used (least, median, most of those samples; None before the loop), and the CPU
    milliseconds a frame cost the coordinator ``pid`` and its nodes together (all their threads: what
    the load of other work does not change) with the frame rate two idle cores would allow."""
    points: list[float] = []
    busy: list[float] = []
    budgets: list[float] = []
    stop = threading.Event()

    def sample() -> None:
        while not stop.wait(0.5):
            stats = client.get(f"/api/sessions/{session}/stats").json()
            nodes = stats["nodes"]
            points.append(max((n.get("points", 0) for n in nodes), default=0))
            busy.append(max((n["busy_ms"] for n in nodes), default=0.0))
            if stats.get("point_budget") is not None:   # the coordinator's loop (before it: a fixed budget)
                budgets.append(stats["point_budget"])

    sampler = threading.Thread(target=sample, daemon=True)
    first_input = viewer.seq + 1
    moving_started = next_send = time.perf_counter()
    sampler.start()
    tree = process_tree(pid)
    cpu_started = cpu_seconds(tree)
    while (now := time.perf_counter()) < moving_started + seconds:
        viewer.send_camera(oblique(bounds, 2.0 * math.pi * (now - moving_started) / 16.0, path))
        next_send += 1.0 / args.input_hz
        time.sleep(max(0.0, next_send - time.perf_counter()))
    ended = time.perf_counter()
    cpu_used = cpu_seconds(tree) - cpu_started
    stop.set()
    sampler.join()
    figures = session_figures(viewer, moving_started + 1.0, ended)
    with viewer.lock:
        frames = sum(1 for f in viewer.frames if moving_started <= f["at"] <= ended and not f["still"])
    cpu_ms = cpu_used * 1e3 / max(frames, 1)
    answer = first_answer(viewer, first_input)
    return {"path": path, "first_answer_s": None if answer is None else round(answer, 2),
            **{k: round(v, 2) for k, v in figures.items()}, "cpu_ms_per_frame": round(cpu_ms, 1),
            "fps_two_idle_cores": round(2000.0 / cpu_ms, 1) if cpu_ms > 0 else None,
            "points_per_frame": round(float(np.median(points)), 0) if points else None,
            "budget_in_use": [round(float(np.percentile(budgets, q))) for q in (0, 50, 100)] if budgets else None,
            "busy_ms": round(float(np.median(busy)), 1) if busy else None, "load": round(os.getloadavg()[0], 1)}


def first_answer(viewer: ScriptedViewer, first_input: int) -> float | None:
    """Seconds from input ``first_input`` to the first frame that answers it or a later input (None: none came)."""
    with viewer.lock:
        at = next((f["at"] for f in viewer.frames if f["input"] >= first_input and not f["still"]), None)
    return None if at is None else at - viewer.sent[first_input]


def resume_after_rests(client: httpx.Client, viewer: ScriptedViewer, session: str, bounds: list[list[float]],
                       args: argparse.Namespace, pid: int) -> list[float | None]:
    """``--rests`` times: the camera rests ``--rest-s`` (a still begins), then moves along the first
    of ``--paths`` for 2 s; the seconds from its first input to the first frame that answers
    (waited for up to :data:`RESUME_WAIT_S`; None: none came)."""
    delays: list[float | None] = []
    for _ in range(args.rests):
        time.sleep(args.rest_s)
        first_input = viewer.seq + 1
        move(client, viewer, session, bounds, args.paths[0], 2.0, args, pid)
        deadline = time.perf_counter() + RESUME_WAIT_S
        while (answer := first_answer(viewer, first_input)) is None and time.perf_counter() < deadline:
            time.sleep(0.05)
        delays.append(None if answer is None else round(answer, 2))
    return delays


def session_run(args: argparse.Namespace, cloud: Path, cache: Path, budget: int) -> dict[str, Any]:
    """One coordinator at ``budget``: its first frame, the picture moving along each of ``--paths``,
    the moving frame against the still of one camera, the peak memory of it and its nodes."""
    coordinator, url = start(args, cloud, cache, budget)
    memory = MemoryPeak(coordinator.pid)
    try:
        with httpx.Client(base_url=url, timeout=600) as client:
            started = time.perf_counter()
            session = open_session(client, f"library/{cloud.name}", args.size)
            wait_session_ready(client, session, timeout=1800)
            first_s = time.perf_counter() - started
            bounds = client.get(f"/api/sessions/{session}/camera").json()["bounds"]
            # One viewer moving without a rest: a rest starts a still, whose samples draw every point
            # (seconds a tile at 100M points on llvmpipe) and hold the next moving frames back. The
            # warm-up outlasts the still that starts after the first frame.
            with ws_client.connect(url.replace("http://", "ws://") + f"/ws/view?session={session}",
                                   max_size=256 << 20) as ws:
                viewer = ScriptedViewer(ws)
                warmup = move(client, viewer, session, bounds, args.paths[0], args.warmup_s, args, coordinator.pid)
                paths = [move(client, viewer, session, bounds, path, args.moving_s, args, coordinator.pid)
                         for path in args.paths]
                resume = resume_after_rests(client, viewer, session, bounds, args, coordinator.pid)
                viewer.stop()
            camera = oblique(bounds, 1.0)
            first = client.put(f"/api/sessions/{session}/camera", json=camera).json()["frame"]
            moving = client.get(f"/api/sessions/{session}/frame.png", params={"after": first}).content
            asked = time.perf_counter()
            try:
                answer = client.get(f"/api/sessions/{session}/frame.png", timeout=args.still_s,
                                    params={"after": first, "still": "true"})
                still: bytes | None = answer.content
                samples: int | None = int(answer.headers.get("x-frame-samples", 0))
            except httpx.TimeoutException:
                still, samples = None, None
            still_s = time.perf_counter() - asked
            every = None if still is None else every_point_still(client, session, int(answer.headers["x-frame-id"]),
                                                                 args, camera)
    finally:
        peaks = memory.stop()
        coordinator.stop(timeout=60.0)
    moving_image = np.asarray(Image.open(io.BytesIO(moving)).convert("RGB"))
    still_image = None if still is None else np.asarray(Image.open(io.BytesIO(still)).convert("RGB"))
    similar = None if still_image is None else psnr(moving_image, still_image)
    if every is not None and isinstance(every.get("image"), np.ndarray):
        image = every.pop("image")
        every["psnr_moving_db"] = round(psnr(moving_image, image), 2)
        every["psnr_first_still_db"] = round(psnr(still_image, image), 2)
    return {"budget": budget, "first_frame_s": round(first_s, 2), "warmup": warmup, "paths": paths,
            "rest_s": args.rest_s, "resume_s": resume, **peaks,
            "psnr_moving_vs_still": None if similar is None else round(similar, 2),
            "still_s": round(still_s, 2) if still is not None else f"over {args.still_s:g}", "still_samples": samples,
            "every_point": every, "load": round(os.getloadavg()[0], 1)}


def every_point_still(client: httpx.Client, session: str, still_id: int, args: argparse.Namespace,
                      camera: dict[str, Any]) -> dict[str, Any] | None:
    """With ``--every-point-s``: the still of every point that follows the first still (frame
    ``still_id``) where that still left points in view out (the nodes' ``points_left_out``) — its
    seconds after the first, samples and (h, w, 3) uint8 ``image`` (saved with the camera in
    ``--save``); None when not asked for."""
    if not args.every_point_s:
        return None
    left_out = sum(int(node.get("points_left_out", 0)) for node in client.get("/api/stats").json()["nodes"])
    if not left_out:
        return {"seconds": "none: the first still left no point out"}
    asked = time.perf_counter()
    try:
        answer = client.get(f"/api/sessions/{session}/frame.png", timeout=args.every_point_s,
                            params={"after": still_id + 1, "still": "true"})
    except httpx.TimeoutException:
        return {"seconds": f"over {args.every_point_s:g} s after the first"}
    figures: dict[str, Any] = {"seconds": round(time.perf_counter() - asked, 2),
                               "samples": int(answer.headers.get("x-frame-samples", 0)),
                               "image": np.asarray(Image.open(io.BytesIO(answer.content)).convert("RGB"))}
    if args.save:
        args.save.mkdir(parents=True, exist_ok=True)
        (args.save / "every_point_still.png").write_bytes(answer.content)
        (args.save / "camera.json").write_text(json.dumps(camera))
    return figures


def measure(args: argparse.Namespace) -> dict[str, Any]:
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    if args.cloud:
        cloud = Path(args.cloud).resolve()
    elif args.terrain:
        cloud = work / f"terrain_{args.terrain}.laz"
        if not cloud.exists():
            write_terrain(cloud, args.terrain)
    else:
        cloud = work / f"pan_points_{args.scan_copies}x{args.scan_copies}.ply"
        if not cloud.exists():
            write_scan_points(cloud, DEFAULT_SCAN, args.scan_copies)
    with contextlib.ExitStack() as stack:
        if args.cache:
            cache = Path(args.cache)
            cache.mkdir(parents=True, exist_ok=True)
        else:
            cache = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="tessera-bench-points-",
                                                                         dir=args.work)))
        result: dict[str, Any] = {"cloud": cloud.name, "bytes": cloud.stat().st_size, "nodes": args.nodes,
                                  "size": list(args.size), "load_before": round(os.getloadavg()[0], 1)}
        result["ingest"] = ingest(cloud, cache)
        result["ingest"]["load"] = round(os.getloadavg()[0], 1)
        result["runs"] = [session_run(args, cloud, cache, budget) for budget in args.budgets]
    return result


def report(result: dict[str, Any]) -> str:
    ingest_figures = result["ingest"]
    lines = [f"{result['cloud']}: {ingest_figures['points']} points, {result['bytes'] / 1e6:.0f} MB, "
             f"{result['nodes']} nodes, {result['size'][0]}x{result['size'][1]}",
             (f"ingest: {ingest_figures['points_per_s'] / 1e6:.2f} M points/s ({ingest_figures['wall_s']:.1f} s; read "
              f"{ingest_figures['read_s']} s; {ingest_figures['cpu_s']:.1f} CPU s, "
              f"{ingest_figures['points_per_cpu_s'] / 1e6:.2f} M/CPU s; peak {ingest_figures['peak_mb']:.0f} MB; "
              f"{ingest_figures['nodes']} octree nodes; load {ingest_figures['load']})"
              if ingest_figures["built"] else
              f"ingest: none, the cache held the cloud (the file hashed and the entry opened in "
              f"{ingest_figures['wall_s']:.1f} s; {ingest_figures['nodes']} octree nodes; "
              f"load {ingest_figures['load']})"),
             f"{'budget':>10} {'path':>9} {'fps':>6} {'lat ms':>7} {'points':>9} {'busy ms':>8} {'CPU ms':>7} "
             f"{'fps 2c':>6} {'budget in use':>25} {'load':>5}"]
    for run in result["runs"]:
        for row in run["paths"]:
            lines.append(f"{run['budget']:>10} {row['path']:>9} {row['fps']:>6} {row['latency_p50_ms']:>7} "
                         f"{row['points_per_frame']!s:>9} {row['busy_ms']!s:>8} {row['cpu_ms_per_frame']:>7} "
                         f"{row['fps_two_idle_cores']!s:>6} {budget_range(row.get('budget_in_use')):>25} "
                         f"{row['load']:>5}")
        lines.append(f"{run['budget']:>10}: first frame {run['first_frame_s']} s; warm-up fps {run['warmup']['fps']} "
                     f"(first answered in {run['warmup']['first_answer_s']} s); moving again after a rest of "
                     f"{run['rest_s']:g} s: first frame in {run['resume_s']} s; worst fps "
                     f"{min(row['fps'] for row in run['paths'])}; PSNR moving vs still {run['psnr_moving_vs_still']} "
                     f"dB (still {run['still_s']} s, {run['still_samples']} samples); "
                     f"{every_point_line(run.get('every_point'))}"
                     f"peak memory {run['peak_pss_mb'] / 1024:.1f} GiB PSS "
                     f"({run['peak_rss_mb'] / 1024:.1f} GiB RSS summed; each process's peak RSS "
                         f"{run['peak_rss_each_mb'][:6]} MB); load {run['load']}")
    return "\n".join(lines)


def every_point_line(every: dict[str, Any] | None) -> str:
    """The still of every point's figures (``--every-point-s``), or nothing."""
    if every is None:
        return ""
    if "samples" not in every:
        return f"still of every point: {every['seconds']}; "
    return (f"still of every point {every['seconds']} s after the first ({every['samples']} samples; PSNR moving vs it "
            f"{every['psnr_moving_db']} dB, first still vs it {every['psnr_first_still_db']} dB); ")


def budget_range(budgets: list[int] | None) -> str:
    """The budget in use along a path: "least / median / most", "fixed" before the loop."""
    return "fixed" if budgets is None else " / ".join(str(b) for b in budgets)


def parse_paths(text: str) -> list[str]:
    """``--paths``: names of :data:`PATHS`, comma-separated."""
    names = text.split(",")
    if unknown := [name for name in names if name not in PATHS]:
        raise argparse.ArgumentTypeError(f"unknown paths {unknown}: of {', '.join(PATHS)}")
    return names


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.points", description=__doc__.split("\n\n")[0])
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--terrain", type=parse_point_budget, metavar="N", help="a synthetic LAZ terrain of N points")
    source.add_argument("--scan-copies", type=int, metavar="K", help="K x K copies of the Pan scan's vertices")
    source.add_argument("--cloud", help="a point cloud file (LAS, LAZ, PLY without faces)")
    parser.add_argument("--nodes", type=int, default=3)
    parser.add_argument("--size", type=size_parser(16, 8192), default=(1280, 720))
    parser.add_argument("--budgets", type=lambda text: [parse_point_budget(v) for v in text.split(",")],
                        default=[500_000], help="the coordinator's --point-budget of each run: where the "
                        "budget starts (its loop then follows --target-fps)")
    parser.add_argument("--fixed-budget", action="store_true",
                        help="each run's budget fixed (--point-budget-min and -max the same): no loop")
    parser.add_argument("--paths", type=parse_paths, default=list(PATHS),
                        help=f"camera paths, of {', '.join(PATHS)} (default all)")
    parser.add_argument("--moving-s", type=float, default=8.0)
    parser.add_argument("--warmup-s", type=float, default=15.0,
                        help="seconds moved before the paths are measured (the first still's samples drain)")
    parser.add_argument("--input-hz", type=float, default=30.0)
    parser.add_argument("--rests", type=int, default=3,
                        help="times the camera rests and moves again after the paths (default 3)")
    parser.add_argument("--rest-s", type=float, default=3.0,
                        help="seconds of each rest: a still begins (default 3)")
    parser.add_argument("--work", default=str(Path(tempfile.gettempdir()) / "tessera-bench-points"))
    parser.add_argument("--cache", help="a scene cache folder kept between runs (default: a fresh one, "
                        "removed after); ingest figures are of a build only when it holds no entry of the cloud")
    parser.add_argument("--still-s", type=float, default=1200.0,
                        help="seconds the still may take before it is reported as not done")
    parser.add_argument("--every-point-s", type=float, default=0.0,
                        help="seconds the still of every point, which follows a first still that left points in view "
                        "out, may take after it (default 0: not waited for)")
    parser.add_argument("--save", type=Path, help="a folder for the still of every point and its camera (JSON)")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
    result = measure(args)
    show_result(report(result), result, args.json, argv if argv is not None else sys.argv[1:])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
