"""A big model as a user opens and moves it (issues 31 and 32): time from ``POST /api/sessions`` to
its first frame with no scene cache (ingest included) and after a restart (cache kept), each node's
peak memory, then the picture moving with levels of detail on and off.

``python -m bench.bigscene --scene PATH [--nodes 3] [--size 640x360] [--modes sort-first,sort-last]
[--lod on,off] [--moving-s 8] [--input-hz 60] [--moving-size 1280x720] [--orbit 8] [--near 4]
[--lod-max-error-px PX] [--interactive-quality Q] [--peer] [--cache-dir DIR] [--warm-runs 1] [--json OUT]``

For each mode (``--mode`` of the coordinator), in a fresh scene cache folder:

- ``cold``: a coordinator with ``--local-nodes N`` (its library the scene's folder) is started, a
  session of the scene opened, and the seconds until its first frame taken; each node's peak
  resident memory (VmHWM of the node process, and of its scene reader children apart) and the MB
  it holds for the scene (``/api/stats``); with levels of detail on, then the seconds until every
  node holds the levels (built and written to the cache, as while a user moves the model);
- ``warm``: the same after stopping and starting coordinator and nodes again, the cache kept;
- for each ``--lod`` setting (the coordinator's ``--lod-error-px``: its default, or 0), once every
  node holds the model (and the levels) and has been calibrated (``settled_s`` after the first
  frame; ``calibrated`` false: not within :data:`CALIBRATION_WAIT_S`): the model as the
  coordinator's own scene (one session, no still), a scripted viewer orbits the camera at
  ``--input-hz`` for ``--moving-s`` at ``--moving-size``: frames per second, input → frame
  latency (p50, ms and frame intervals), the triangles the nodes drew per frame (summed over the
  nodes with a tile in it), the nodes' busy time per frame, the bound in use, the CPU ms a frame of
  the coordinator, each node, the scripted viewer and the whole machine (others' work included;
  from 1 s after the motion began); then the moving frame (the session's bound kept from the
  motion) from the last camera turned 0.05 rad and, with ``--orbit`` and ``--near``, from the
  cameras of ``bench.lod_cameras`` around it (eight on a turn, four at half the distance) against
  ``--render-once --interactive`` at full detail (PSNR; with ``--msaa 1`` in the depth modes, whose
  layers are drawn at one sample a pixel) and against that frame through the same JPEG (the
  interactive quality: the moving frame a user would get without levels), each camera's and the
  worst camera's. ``--lod-max-error-px`` and ``--interactive-quality`` are passed to the
  coordinator (the moving phase's) when given.

``--peer``: PyVista (``pip install pyvista``), as a user would open the same file in one process:
seconds to its first picture at ``--size`` (read included), the next frame after a 5° turn, and
its peak resident memory (offscreen, on the same Mesa EGL).
"""

from __future__ import annotations

import argparse
import io
import json
import os
import shutil
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

from bench.images import psnr
from bench.live import ScriptedViewer, render_once
from bench.lod_cameras import cameras_around, jpeg
from bench.processes import (
    PYTHON,
    REPO,
    cpu_seconds,
    local_node_pids,
    orbit,
    process_tree,
    show_result,
    start_coordinator,
)
from bench.sessions import move, open_session, session_figures, wait_session_ready
from tessera.cli_values import size_parser
from tessera.geometry import Camera
from tessera.scheduling.config import SchedulerConfig

SIZE_TEXT = "{}x{}"


def peak_mb(pid: int) -> float:
    """VmHWM of process ``pid`` in MiB (0 when it is gone)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


def machine_busy_s() -> float:
    """CPU seconds the whole machine spent not idle since boot (/proc/stat: all but idle and iowait)."""
    fields = [int(v) for v in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    return (sum(fields[:8]) - fields[3] - fields[4]) / os.sysconf("SC_CLK_TCK")


def cpu_sample(coordinator_pid: int, nodes: list[int]) -> dict[str, Any]:
    """CPU seconds so far of the coordinator, each node, this process (the scripted viewer) and
    the whole machine, with the wall clock (s)."""
    return {"at": time.perf_counter(), "coordinator": cpu_seconds([coordinator_pid]),
            "nodes": [cpu_seconds([pid]) for pid in nodes], "viewer": cpu_seconds([os.getpid()]),
            "machine": machine_busy_s()}


def cpu_per_frame(before: dict[str, Any], after: dict[str, Any], frames: float) -> dict[str, Any]:
    """Between two :func:`cpu_sample`\\ s: CPU ms a frame of the coordinator, each node, the viewer, all
    of them and the whole machine (others' work included), and the cores the machine had busy."""
    per = 1000.0 / max(frames, 1.0)
    nodes = [(b - a) * per for a, b in zip(before["nodes"], after["nodes"], strict=True)]
    ours = {key: (after[key] - before[key]) * per for key in ("coordinator", "viewer")}
    return {"node_cpu_ms": [round(v, 1) for v in nodes], "coordinator_cpu_ms": round(ours["coordinator"], 1),
            "viewer_cpu_ms": round(ours["viewer"], 1), "session_cpu_ms": round(sum(nodes) + sum(ours.values()), 1),
            "machine_cpu_ms": round((after["machine"] - before["machine"]) * per, 1),
            "machine_cores_busy": round((after["machine"] - before["machine"]) / (after["at"] - before["at"]), 2)}


def node_peaks(coordinator_pid: int) -> list[dict[str, float]]:
    """Each local node's peak memory and its scene reader children's (MiB)."""
    nodes = local_node_pids(coordinator_pid)
    return [{"node_mb": round(peak_mb(pid), 1),
             "readers_mb": round(max((peak_mb(child) for child in process_tree(pid)[1:]), default=0.0), 1)}
            for pid in nodes]


def start(args: argparse.Namespace, mode: str, cache: Path, *extra: str,
          size: tuple[int, int] | None = None) -> tuple[Any, str]:
    """The coordinator and its local nodes; with ``--logs DIR`` their log (level info: when each
    node joined, held each scene) goes to a new file there."""
    scene = Path(args.scene).resolve()
    flags = ["--local-nodes", str(args.nodes), "--scenes-dir", str(scene.parent), "--mode", mode,
             "--frame-wait-s", "600", "--size", SIZE_TEXT.format(*(size or args.size)), *extra]
    log_path = None
    if args.logs is not None:
        args.logs.mkdir(parents=True, exist_ok=True)
        log_path = args.logs / f"{mode}-{time.strftime('%H%M%S')}-{len(list(args.logs.iterdir()))}.log"
    return start_coordinator(flags, log_level="warning" if log_path is None else "info", timeout=120,
                             log_path=log_path,
                             env={"TESSERA_SCENE_CACHE_DIR": str(cache), "TESSERA_SCENE_MEMORY_MB": "20000"})


def first_frame(args: argparse.Namespace, mode: str, cache: Path, levels: bool = False) -> dict[str, Any]:
    """Start, open the session, time its first frame, take the nodes' peaks; with ``levels``, then
    wait until every node holds the levels of detail (so that a restart finds them in the cache,
    as after a session a user moved in) and time that too; stop."""
    coordinator, url = start(args, mode, cache)
    try:
        with httpx.Client(base_url=url, timeout=600) as client:
            started = time.perf_counter()
            session = open_session(client, f"library/{Path(args.scene).name}", args.size)
            wait_session_ready(client, session, timeout=1800)
            seconds = time.perf_counter() - started
            stats = client.get(f"/api/sessions/{session}").json()
            nodes = client.get("/api/stats").json()["nodes"]
            figures = {"first_frame_s": round(seconds, 2), "peaks": node_peaks(coordinator.process.pid),
                       "scene_mb": stats.get("scene_mb"), "rss_mb": [n.get("rss_mb") for n in nodes]}
            if levels:
                wait_levels(client, session)
                figures["levels_s"] = round(time.perf_counter() - started, 2)
                figures["peaks_with_levels"] = node_peaks(coordinator.process.pid)
            return figures
    finally:
        coordinator.stop(timeout=60.0)


def wait_levels(client: httpx.Client, session: str, timeout: float = 900.0) -> None:
    """Until every node that holds the session's scene holds its levels of detail."""
    deadline = time.monotonic() + timeout
    while client.get(f"/api/sessions/{session}").json()["lod_error_px"] is None:
        if time.monotonic() > deadline:
            raise RuntimeError(f"the nodes did not hold the levels of detail within {timeout:.0f} s")
        time.sleep(0.5)


#: Longest wait for the nodes' calibration before the moving phase begins anyway (s).
CALIBRATION_WAIT_S = 240.0


def wait_settled(client: httpx.Client, session: str, nodes: int, lod: bool,
                 timeout: float = 900.0) -> tuple[float, bool]:
    """Until every one of ``nodes`` holds the session's scene (and, with ``lod``, its levels), then
    until they have been calibrated, at most :data:`CALIBRATION_WAIT_S` (a calibration holds a
    node's GL thread: before, the moving phase began while the first node alone drew); the seconds
    it took and whether they were calibrated."""
    started = time.monotonic()
    while True:
        summary = client.get(f"/api/sessions/{session}").json()
        held = len(summary.get("scene_mb") or {}) >= nodes and summary.get("loading") is None
        if held and (not lod or summary["lod_error_px"] is not None):
            break
        if time.monotonic() - started > timeout:
            raise RuntimeError(f"the {nodes} nodes did not hold the scene within {timeout:.0f} s")
        time.sleep(0.5)
    held_at = time.monotonic()
    while True:
        listed = client.get(f"/api/sessions/{session}/stats").json()["nodes"]
        calibrated = len(listed) >= nodes and all(n.get("calibration_ms") is not None for n in listed)
        if calibrated or time.monotonic() - held_at > CALIBRATION_WAIT_S:
            return time.monotonic() - started, calibrated
        time.sleep(0.5)


def drawn_triangles(nodes: list[dict[str, Any]]) -> int:
    """The triangles the nodes drew in the session's last frame: those of nodes with a tile in it
    (a node without one reports what it holds, or its last frame's)."""
    return sum(int(n.get("triangles", 0)) for n in nodes if n.get("tiles"))


def moving(args: argparse.Namespace, mode: str, cache: Path, lod: str) -> dict[str, Any]:
    """The moving phase with levels of detail ``lod`` ("on": the coordinator's default, "off": 0):
    the model is the coordinator's own scene (the default session, alone: the nodes' figures are
    its frames'), at ``--moving-size``, without a still (the frame compared is a moving one), once
    every node holds it and has been calibrated."""
    extra = [] if lod == "on" else ["--lod-error-px", "0"]
    if args.lod_max_error_px is not None:
        extra += ["--lod-max-error-px", f"{args.lod_max_error_px:g}"]
    if args.interactive_quality is not None:
        extra += ["--interactive-quality", str(args.interactive_quality)]
    quality = args.interactive_quality or SchedulerConfig().interactive_quality
    coordinator, url = start(args, mode, cache, "--scene", str(Path(args.scene).resolve()), "--still-codec", "none",
                             *extra, size=args.moving_size)
    try:
        with httpx.Client(base_url=url, timeout=600) as client:
            session = "default"
            wait_session_ready(client, session, timeout=1800)
            settled_s, calibrated = wait_settled(client, session, args.nodes, lod == "on")
            ws_url = url.replace("http://", "ws://") + "/ws/view"
            with ws_client.connect(ws_url, max_size=256 << 20) as ws:
                viewer = ScriptedViewer(ws)
                triangles: list[float] = []
                busy: list[float] = []
                bounds: list[float] = []
                stop = threading.Event()

                def sample() -> None:
                    while not stop.wait(0.5):
                        stats = client.get(f"/api/sessions/{session}/stats").json()
                        triangles.append(drawn_triangles(stats["nodes"]))
                        busy.append(max((n["busy_ms"] for n in stats["nodes"]), default=0.0))
                        summary = client.get(f"/api/sessions/{session}").json()
                        bounds.append(summary["lod_error_px"] or 0.0)

                sampler = threading.Thread(target=sample, daemon=True)
                pids = local_node_pids(coordinator.process.pid)
                started = time.perf_counter()
                sampler.start()
                cpu_before: dict[str, Any] = {}
                timer = threading.Timer(1.0, lambda: cpu_before.update(cpu_sample(coordinator.process.pid, pids)))
                timer.start()
                move([viewer], started + args.moving_s, args.input_hz, 8.0, threading.Event())
                timer.join()
                cpu_after = cpu_sample(coordinator.process.pid, pids)
                ended = time.perf_counter()
                stop.set()
                sampler.join()
                figures = session_figures(viewer, started + 1.0, ended)
                cpu = cpu_per_frame(cpu_before, cpu_after, figures["fps"] * (ended - started - 1.0))
                base = Camera.from_json(orbit(viewer.camera, 0.05))
                named = cameras_around(base, args.orbit, args.near) if args.orbit else [("last", base)]
                frames = [(name, camera.to_json(), moving_frame(client, session, camera.to_json()))
                          for name, camera in named]
                viewer.stop()
    finally:
        coordinator.stop(timeout=60.0)
    one_sample = ("--msaa", "1") if mode != "sort-first" else ()   # depth layers are drawn at one sample
    compared = []
    for name, camera, image in frames:
        full = render_once(str(Path(args.scene).resolve()), camera, args.moving_size, "--interactive", *one_sample,
                           "--scene-cache-dir", str(cache))
        compared.append({"camera": name, "psnr_vs_full": round(psnr(image, full), 2),
                         "psnr_vs_full_jpeg": round(psnr(image, jpeg(full, quality)), 2)})
    return {**{k: round(v, 2) for k, v in figures.items()},
            "triangles_per_frame": round(float(np.median(triangles)), 0) if triangles else None,
            "busy_ms": round(float(np.median(busy)), 1) if busy else None,
            "bound_px": round(float(np.median(bounds)), 2) if bounds else None,
            "bound_max_px": round(float(np.max(bounds)), 2) if bounds else None,
            "settled_s": round(settled_s, 1), "calibrated": calibrated, **cpu, "quality": quality,
            "psnr_vs_full": compared[0]["psnr_vs_full"], "psnr_vs_full_jpeg": compared[0]["psnr_vs_full_jpeg"],
            "worst_vs_full": min(compared, key=lambda c: c["psnr_vs_full"]),
            "worst_vs_full_jpeg": min(compared, key=lambda c: c["psnr_vs_full_jpeg"]), "cameras": compared}


def moving_frame(client: httpx.Client, session: str, camera: dict[str, Any]) -> np.ndarray:
    """The session's next frame after its camera is put at ``camera`` (a moving frame: at the
    levels of detail of the bound in use), (h, w, 3) uint8."""
    first = client.put(f"/api/sessions/{session}/camera", json=camera).json()["frame"]
    response = client.get(f"/api/sessions/{session}/frame.png", params={"after": first})
    if response.headers.get("x-frame-still") == "1" or int(response.headers.get("x-frame-samples", 0)) > 1:
        raise RuntimeError("the frame compared is not a moving frame")
    return np.asarray(Image.open(io.BytesIO(response.content)).convert("RGB"))


PEER = r"""
import json, resource, sys, time
started = time.perf_counter()
import pyvista as pv
mesh = pv.read(sys.argv[1])
plotter = pv.Plotter(off_screen=True, window_size=[int(sys.argv[2]), int(sys.argv[3])])
plotter.add_mesh(mesh, color="lightgray")
plotter.show(auto_close=False)
plotter.screenshot(None)
first = time.perf_counter() - started
turned = time.perf_counter()
plotter.camera.azimuth = 5.0
plotter.render()
plotter.screenshot(None)
print(json.dumps({"first_picture_s": round(first, 2), "next_frame_s": round(time.perf_counter() - turned, 2),
                  "peak_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
                  "triangles": int(mesh.n_cells)}))
"""


def peer(args: argparse.Namespace) -> dict[str, Any] | None:
    """PyVista's first picture of the scene (None when it is not installed or fails)."""
    done = subprocess.run([PYTHON, "-c", PEER, str(Path(args.scene).resolve()), *map(str, args.size)], cwd=REPO,
                          capture_output=True, text=True, timeout=1800)
    if done.returncode != 0:
        print(f"PyVista failed: {done.stderr.strip().splitlines()[-1:]}", file=sys.stderr)
        return None
    result: dict[str, Any] = json.loads(done.stdout.strip().splitlines()[-1])
    return result


def measure(args: argparse.Namespace) -> dict[str, Any]:
    result: dict[str, Any] = {"scene": str(args.scene), "nodes": args.nodes, "size": list(args.size), "modes": {}}
    if args.peer:
        result["pyvista"] = peer(args)
    for mode in args.modes.split(","):
        kept = args.cache_dir is not None
        cache = args.cache_dir / mode if kept else Path(tempfile.mkdtemp(prefix="tessera-bigscene-"))
        cache.mkdir(parents=True, exist_ok=True)
        try:
            figures: dict[str, Any] = {}
            if not (kept and any(cache.iterdir())):
                figures["cold"] = first_frame(args, mode, cache, levels="on" in args.lod.split(","))
            figures["warm"] = first_frame(args, mode, cache)
            for round_ in range(1, args.warm_runs):
                figures[f"warm{round_ + 1}"] = first_frame(args, mode, cache)
            for lod in args.lod.split(",") if args.moving_s > 0 else ():
                figures[f"moving_lod_{lod}"] = moving(args, mode, cache, lod)
            result["modes"][mode] = figures
        finally:
            if not kept:
                shutil.rmtree(cache, ignore_errors=True)
        print(json.dumps({mode: figures}), flush=True)
    return result


def report(result: dict[str, Any]) -> str:
    lines = [f"{result['scene']}: {result['nodes']} nodes, first frames at {SIZE_TEXT.format(*result['size'])}"]
    if result.get("pyvista"):
        p = result["pyvista"]
        lines.append(f"  PyVista: first picture {p['first_picture_s']} s, next frame {p['next_frame_s']} s, "
                     f"peak {p['peak_mb']:.0f} MB")
    for mode, figures in result["modes"].items():
        for phase in [key for key in figures if key == "cold" or key.startswith("warm")]:
            f = figures[phase]
            peaks = ", ".join(f"{p['node_mb']:.0f}/{p['readers_mb']:.0f}" for p in f["peaks"])
            levels = f" (levels held after {f['levels_s']} s)" if "levels_s" in f else ""
            lines.append(f"  {mode:10s} {phase}: first frame {f['first_frame_s']:6.2f} s{levels}; "
                         f"node/readers peak MB {peaks}")
        for key, f in figures.items():
            if key.startswith("moving"):
                lines.append(f"  {mode:10s} {key}: {f['fps']:.1f} fps, latency p50 {f['latency_p50_ms']:.0f} ms "
                             f"({f['latency_p50_frames']:.1f} frames), {f['triangles_per_frame']} triangles/frame, "
                             f"busy {f['busy_ms']} ms, bound {f['bound_px']} px, PSNR {f['psnr_vs_full']} dB "
                             f"({f['psnr_vs_full_jpeg']} dB against full detail's JPEG)")
                if len(f.get("cameras", ())) > 1:
                    raw, coded = f["worst_vs_full"], f["worst_vs_full_jpeg"]
                    lines.append(f"  {'':10s} worst of {len(f['cameras'])} cameras: {raw['psnr_vs_full']} dB "
                                 f"({raw['camera']}), {coded['psnr_vs_full_jpeg']} dB against full detail's JPEG "
                                 f"({coded['camera']})")
                if "node_cpu_ms" in f:
                    lines.append(f"  {'':10s} CPU ms a frame: nodes {f['node_cpu_ms']}, coordinator "
                                 f"{f['coordinator_cpu_ms']}, viewer {f['viewer_cpu_ms']}, machine "
                                 f"{f['machine_cpu_ms']} ({f['machine_cores_busy']} cores busy)")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.bigscene", description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", type=Path, required=True, help="the model file (its folder is the library)")
    parser.add_argument("--nodes", type=int, default=3)
    parser.add_argument("--size", type=size_parser(16, 16384), default=(640, 360), help="first frames' size")
    parser.add_argument("--modes", default="sort-first,sort-last")
    parser.add_argument("--lod", default="on,off", help="levels of detail in the moving phase: on, off or both")
    parser.add_argument("--moving-s", type=float, default=8.0, help="0: no moving phase")
    parser.add_argument("--moving-size", type=size_parser(16, 16384), default=(1280, 720))
    parser.add_argument("--input-hz", type=float, default=60.0)
    parser.add_argument("--lod-max-error-px", type=float, help="the coordinator's (default: its default)")
    parser.add_argument("--interactive-quality", type=int, help="the coordinator's (default: its default)")
    parser.add_argument("--orbit", type=int, default=8,
                        help="the moving frame compared from this many cameras on a turn (0: the last camera alone)")
    parser.add_argument("--near", type=int, default=4, help="and from this many at half the distance")
    parser.add_argument("--peer", action="store_true", help="PyVista's first picture of the same file")
    parser.add_argument("--cache-dir", type=Path,
                        help="keep each mode's scene cache in a folder of this one; one that holds an entry "
                             "already skips the cold run (only warm first frames are measured)")
    parser.add_argument("--warm-runs", type=int, default=1, help="warm first frames measured in turn")
    parser.add_argument("--json", type=Path)
    parser.add_argument("--logs", type=Path, help="keep each run's coordinator and node log (level info) here")
    args = parser.parse_args(argv)
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    result = measure(args)
    show_result(report(result), result, args.json, argv)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
