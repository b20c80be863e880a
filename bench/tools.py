"""What users do with a model on the live service (issue 35): picking, a section box, a poster, a
film, each on a coordinator with N local nodes and its defaults.

``python -m bench.tools KIND [--scene S] [--nodes 3] [--size WxH] [--mode M] [--json OUT]`` with KIND
one of (``--mode``: the coordinator's decomposition mode, sort-first by default):

* ``pick``: while a scripted user turns the camera (``PUT /api/camera`` at 30 Hz), ``--picks``
  picks of pixels near the middle, one at a time; each pick's time (request to answer) in ms and
  in frame intervals (the mean interval between the frames published meanwhile), p50, p90, max;
  and the picks' time at rest.
* ``section``: the frame rate while the camera turns, without a cut and with a section box over
  the middle ``--box`` of the scene along x (A, B, A, B windows of ``--seconds`` each, so load
  changes touch both), the triangles the nodes drew per frame; then the still of the boxed session
  at rest against ``python -m node --render-once --clip`` of the same camera (PSNR, pixels off).
* ``poster``: a poster of ``--poster WxH`` and one of the frame's ``--size`` (``--samples`` each):
  the node time per pixel (and per sample) of each, from the job's ``node_ms``, their ratio, and the
  live interactive frame's node time per pixel while the camera turns; wall time.
* ``film``: a ``--seconds`` orbit at ``--fps`` of ``--size``: wall time from the request to the MP4,
  the frames' node time (the job's ``node_ms``), wall ÷ (node time ÷ nodes), and the frames the
  MP4 plays back (PyAV).

Posters and films also report the coordinator process's CPU time while the job ran and the part
of it spent merging depth tiles (sort-last).

Everything shares this machine's cores with whatever else runs: the figures come with the load
average before and after.
"""

from __future__ import annotations

import argparse
import io
import json
import math
import os
import subprocess
import tempfile
import threading
import time
import urllib.request
from collections.abc import Callable
from pathlib import Path
from typing import Any

import av
import numpy as np
from PIL import Image

from bench.images import psnr
from bench.processes import PYTHON, REPO, orbit, show_result, start_coordinator
from tessera.decomposition.modes import MODES

DEFAULT_SCENE = str(REPO.parent / "shared" / "scenes" / "large_scan" / "threedscans_pan_990k.ply")


class Service:
    """A coordinator with ``nodes`` local nodes on ``scene`` at ``size``, its API."""

    def __init__(self, scene: str, nodes: int, size: tuple[int, int], extra: list[str]) -> None:
        self.process, self.url = start_coordinator(["--scene", scene, "--size", f"{size[0]}x{size[1]}",
                                                    "--local-nodes", str(nodes), "--max-poster-size",
                                                    "16384x16384", *extra], timeout=120.0)
        self.nodes, self.size = nodes, size
        self.wait(lambda: sum(n["state"] == "ready" for n in self.call("/api/stats")["nodes"]) == nodes, 900,
                  "the nodes to load the scene")
        self.wait(lambda: self.call("/api/stats")["settled"], 900, "the first still")

    def call(self, path: str, method: str = "GET", body: Any = None, timeout: float = 600.0) -> Any:
        data = None if body is None else json.dumps(body).encode()
        request = urllib.request.Request(self.url + path, data=data, method=method,
                                         headers={"content-type": "application/json"})
        with urllib.request.urlopen(request, timeout=timeout) as response:
            payload = response.read()
            return json.loads(payload) if response.headers.get("content-type", "").startswith("application/json") \
                else payload

    @staticmethod
    def wait(condition: Callable[[], Any], timeout_s: float, what: str) -> Any:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if value := condition():
                return value
            time.sleep(0.2)
        raise RuntimeError(f"timed out waiting for {what}")

    def stop(self) -> None:
        self.process.stop()


class Mover:
    """A user turning the camera slowly about its target, ``hz`` times a second, on a thread."""

    def __init__(self, service: Service, camera: dict[str, Any], hz: float = 30.0) -> None:
        self.service, self.camera, self.hz = service, camera, hz
        self.stop_event = threading.Event()
        self.thread = threading.Thread(target=self.run, daemon=True)

    def run(self) -> None:
        step = 0
        while not self.stop_event.wait(1.0 / self.hz):
            self.service.call("/api/camera", "PUT", orbit(self.camera, 0.25 * math.sin(step / 40.0)))
            step += 1

    def __enter__(self) -> Mover:
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop_event.set()
        self.thread.join(timeout=30)


def load() -> float:
    return round(os.getloadavg()[0], 1)


def frames_per_s(service: Service, seconds: float) -> tuple[float, float]:
    """Frames published per second over ``seconds``, and the triangles the nodes drew in the last
    frame (each node's last frame's counters)."""
    first, started = service.call("/api/stats")["coordinator_cpu"]["frames"], time.monotonic()
    time.sleep(seconds)
    stats = service.call("/api/stats")
    fps = (stats["coordinator_cpu"]["frames"] - first) / (time.monotonic() - started)
    return fps, float(sum(n.get("triangles", 0) for n in stats["nodes"]))


def percentiles(values: list[float]) -> dict[str, float]:
    return {"p50": round(float(np.percentile(values, 50)), 2), "p90": round(float(np.percentile(values, 90)), 2),
            "max": round(max(values), 2)}


def bench_pick(service: Service, picks: int) -> dict[str, Any]:
    width, height = service.size
    rng = np.random.default_rng(35)
    camera = service.call("/api/camera")["camera"]
    out: dict[str, Any] = {}
    for phase in ("moving", "rest"):
        times, hits = [], 0
        with Mover(service, camera) if phase == "moving" else _nothing():
            time.sleep(2.0 if phase == "moving" else 0.0)
            started_frame, started = service.call("/api/stats")["coordinator_cpu"]["frames"], time.monotonic()
            for _ in range(picks):
                x = int(width * rng.uniform(0.3, 0.7))
                y = int(height * rng.uniform(0.3, 0.7))
                t0 = time.perf_counter()
                answer = service.call(f"/api/pick?x={x}&y={y}")
                times.append((time.perf_counter() - t0) * 1e3)
                hits += bool(answer["hit"])
                time.sleep(0.1)
            frames = service.call("/api/stats")["coordinator_cpu"]["frames"] - started_frame
        out[phase] = {"picks": picks, "hits": hits, "pick_ms": percentiles(times)}
        if phase == "moving":   # at rest no frame comes: no frame interval to count in
            interval_ms = (time.monotonic() - started) * 1e3 / max(frames, 1)
            out[phase].update(frames=frames, frame_interval_ms=round(interval_ms, 1),
                              pick_intervals=percentiles([t / interval_ms for t in times]))
    return out


class _nothing:
    def __enter__(self) -> None:
        return None

    def __exit__(self, *exc: object) -> None:
        return None


def bench_section(service: Service, seconds: float, fraction: float, scene: str) -> dict[str, Any]:
    state = service.call("/api/camera")
    camera, bounds = state["camera"], np.asarray(state["bounds"])
    lo, hi = bounds
    middle = (lo + hi) / 2
    box = {"min": [float(middle[0] - fraction / 2 * (hi[0] - lo[0])), float(lo[1] - 1), float(lo[2] - 1)],
           "max": [float(middle[0] + fraction / 2 * (hi[0] - lo[0])), float(hi[1] + 1), float(hi[2] + 1)]}
    windows: dict[str, list[tuple[float, float]]] = {"none": [], "box": []}
    with Mover(service, camera):
        time.sleep(2.0)
        for name in ("none", "box", "none", "box"):
            service.call("/api/clip", "PUT", {"box": box} if name == "box" else {})
            time.sleep(1.0)
            windows[name].append(frames_per_s(service, seconds))
    fps = {name: round(float(np.mean([w[0] for w in values])), 2) for name, values in windows.items()}
    triangles = {name: int(np.mean([w[1] for w in values])) for name, values in windows.items()}
    service.call("/api/clip", "PUT", {"box": box})
    service.call("/api/camera", "PUT", camera)
    service.wait(lambda: service.call("/api/stats")["settled"], 900, "the boxed still")
    still = np.asarray(Image.open(io.BytesIO(service.call("/api/frame.png?still=true"))).convert("RGB"))
    with tempfile.TemporaryDirectory() as folder:
        paths = {name: Path(folder) / f"{name}.json" for name in ("camera", "clip")}
        paths["camera"].write_text(json.dumps(camera))
        paths["clip"].write_text(json.dumps({"box": box}))
        out_png = Path(folder) / "reference.png"
        subprocess.run([PYTHON, "-m", "node", "--render-once", str(out_png), "--scene", scene, "--camera",
                        str(paths["camera"]), "--clip", str(paths["clip"]), "--size",
                        f"{service.size[0]}x{service.size[1]}"], cwd=REPO, check=True, capture_output=True)
        reference = np.asarray(Image.open(out_png).convert("RGB"))
    off = float((np.abs(still.astype(int) - reference).max(axis=2) > 8).mean())
    return {"box_fraction": fraction, "fps_moving": fps, "fps_ratio": round(fps["box"] / max(fps["none"], 1e-9), 2),
            "triangles_per_frame": triangles, "still_psnr": round(min(psnr(still, reference), 100.0), 2),
            "still_off_fraction": off}


def run_job(service: Service, route: str, body: dict[str, Any]) -> tuple[dict[str, Any], float, bytes]:
    """A job's final state (with ``coordinator_cpu_s`` and ``merge_s``: the coordinator process's CPU
    time and its depth merging's while it ran), its wall time (s) and its output."""
    before = service.call("/api/stats")["coordinator_cpu"]
    started = time.perf_counter()
    job = service.call(f"/api/{route}", "POST", body)["id"]
    state = service.wait(lambda: (s := service.call(f"/api/{route}/{job}"))["state"] not in ("queued", "rendering")
                         and s, 24 * 3600, f"the {route} job")
    wall = time.perf_counter() - started
    if state["state"] != "done":
        raise RuntimeError(f"{route} {job}: {state}")
    after = service.call("/api/stats")["coordinator_cpu"]
    state["coordinator_cpu_s"] = round((after["process_ms"] - before["process_ms"]) / 1e3, 1)
    state["merge_s"] = round((after["merge_ms"] - before["merge_ms"]) / 1e3, 1)
    suffix = "png" if route == "posters" else "mp4"
    return state, wall, service.call(f"/api/{route}/{job}.{suffix}")


def bench_poster(service: Service, poster: tuple[int, int], samples: int) -> dict[str, Any]:
    camera = service.call("/api/camera")["camera"]
    with Mover(service, camera):
        time.sleep(3.0)
        nodes = service.call("/api/stats")["nodes"]
    live_ms = sum(n.get("busy_ms", 0.0) for n in nodes)
    service.call("/api/camera", "PUT", camera)
    service.wait(lambda: service.call("/api/stats")["settled"], 900, "rest")
    out: dict[str, Any] = {"live_frame_ms_per_mpx": round(live_ms / (service.size[0] * service.size[1]) * 1e6, 1)}
    for name, size in (("frame_size", service.size), ("poster", poster)):
        state, wall, _ = run_job(service, "posters", {"size": list(size), "samples": samples})
        pixels = size[0] * size[1] * samples
        out[name] = {"size": list(size), "samples": samples, "wall_s": round(wall, 1),
                     "node_ms": state["node_ms"], "node_ms_per_mpx_sample": round(state["node_ms"] / pixels * 1e6, 1),
                     "coordinator_cpu_s": state["coordinator_cpu_s"], "merge_s": state["merge_s"]}
    out["per_pixel_ratio"] = round(out["poster"]["node_ms_per_mpx_sample"]
                                   / out["frame_size"]["node_ms_per_mpx_sample"], 3)
    return out


def bench_film(service: Service, seconds: float, fps: float, samples: int) -> dict[str, Any]:
    size = [service.size[0] // 2 * 2, service.size[1] // 2 * 2]
    body = {"orbit": {"turns": 1.0, "seconds": seconds}, "fps": fps, "size": size, "samples": samples}
    state, wall, film = run_job(service, "recordings", body)
    with tempfile.NamedTemporaryFile(suffix=".mp4") as saved:
        saved.write(film)
        saved.flush()
        with av.open(saved.name) as container:
            played = sum(1 for _ in container.decode(video=0))
    ideal_s = state["node_ms"] / 1000.0 / service.nodes
    return {"frames": state["total"], "played_back": played, "size": size, "samples": samples,
            "wall_s": round(wall, 1), "node_ms": state["node_ms"], "node_s_per_node": round(ideal_s, 1),
            "wall_over_node_time": round(wall / ideal_s, 3), "coordinator_cpu_s": state["coordinator_cpu_s"],
            "merge_s": state["merge_s"]}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.tools", description=__doc__.split("\n\n")[0])
    parser.add_argument("kind", choices=("pick", "section", "poster", "film"))
    parser.add_argument("--scene", default=DEFAULT_SCENE)
    parser.add_argument("--nodes", type=int, default=3)
    parser.add_argument("--size", default="1280x720")
    parser.add_argument("--mode", choices=MODES, default="sort-first", help="the coordinator's decomposition mode")
    parser.add_argument("--picks", type=int, default=30)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--box", type=float, default=0.3, help="the section box's share of the scene along x")
    parser.add_argument("--poster", default="8192x8192")
    parser.add_argument("--samples", type=int, default=1)
    parser.add_argument("--fps", type=float, default=30.0)
    parser.add_argument("--server-args", default="")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    size = tuple(int(v) for v in args.size.split("x"))
    before = load()
    service = Service(args.scene, args.nodes, size,   # type: ignore[arg-type]
                      ["--mode", args.mode, *args.server_args.split()])
    try:
        if args.kind == "pick":
            figures = bench_pick(service, args.picks)
        elif args.kind == "section":
            figures = bench_section(service, args.seconds, args.box, args.scene)
        elif args.kind == "poster":
            poster = tuple(int(v) for v in args.poster.split("x"))
            figures = bench_poster(service, poster, args.samples)   # type: ignore[arg-type]
        else:
            figures = bench_film(service, args.seconds, args.fps, args.samples)
    finally:
        service.stop()
    result = {"kind": args.kind, "scene": Path(args.scene).name, "nodes": args.nodes, "mode": args.mode,
              "size": list(size),
              **figures, "load_before": before, "load_after": load()}
    show_result(json.dumps(result, indent=2), result, args.json, argv)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
