"""Video to the browser (issue 21): a camera path played through the live service once per transport
(tiles, then each codec of :class:`tessera.wire.video.VideoCodec`), each watched by a scripted
viewer that decodes what it receives.

``python -m bench.stream [--scene S] [--path P] [--size WxH] [--nodes N] [--moving-s 8]
[--input-hz 60] [--transports tiles,h264,vp9] [--psnr-frames 8] [--synthetic]
[--throttle-mbps R] [--rest-s S] [--resume-s 3] [--server-args "…"] [--json OUT]``

One coordinator (``python -m server --local-nodes N --stream auto``, as :mod:`bench.live` starts
it) serves every transport in turn: per transport a new viewer on ``/ws/view`` sends
``stream_offer`` with only that codec (tiles: none) and checks the ``stream`` answer, then sends
cameras with input numbers at ``--input-hz`` for ``--moving-s``: the camera path ``--path`` (a
``bench/paths/*.json`` file, or a kind of :func:`bench.paths.make_path` made for the scene's
bounds, loaded here; synthetic nodes': their box) played at its own ``dt_ms``, cameras between two
of its frames interpolated, looping. A video viewer sends ``stream_report`` each second, as
``web/video.js`` does. The viewer (:mod:`bench.stream_viewer`) decodes every interactive frame
as it comes. Each viewer connects through a loopback proxy (:mod:`bench.throttle`) that counts
the bytes on the wire; ``--throttle-mbps R``: its coordinator → viewer direction carries R
Mbit/s. ``--rest-s S``: after the moving window the camera rests until the still answering the
last input comes (at most S s), then moves on along the path for ``--resume-s``.

Figures per transport, over the moving window (its first second left out):

* ``fps``: interactive frames decoded per second; ``bytes_per_frame``: mean message size (header
  included); ``mbps``: ``bytes_per_frame`` × 8 × ``fps``; ``wire_bytes_per_frame``, ``wire_mbps``:
  the same of the bytes on the wire, after permessage-deflate, which the coordinator agrees on with
  browsers and with this viewer (JPEG tiles of flat backgrounds shrink to under half; video not); ``mbps_at_60fps``: at
  60 frames/s (the encoder gives each frame the target / the nominal 60 fps whatever the real
  rate, so this is what the link would carry at 60); ``viewer_decode_ms``: this viewer's CPU per
  frame decoding it (tiles: JPEG to RGB; video: PyAV, to YUV);
* ``psnr_mean``, ``psnr_min`` (dB, 100 = identical): ``--psnr-frames`` decoded frames sampled
  evenly in time against the reference of the camera their header's input number names: the
  node's own renderer in this process (:class:`node.gl.renderer.TileRenderer` with a node's default
  settings: the interactive frame, as ``python -m node --render-once --interactive``), after the
  service stopped. ``psnr_source_*``: the
  same frames against the coordinator's lossless composite of the same frame id
  (``GET /api/frame.png?after=ID``, the video encoder's source: the tiles as received), i.e. the
  video codec's own loss (tiles: identical);
* ``encode_ms``, ``compose_ms``: the coordinator's CPU per encoded frame (ms of its stream thread's
  CPU, where the encoder and the tile decoding run alone), ``encode_wall_ms``, ``compose_wall_ms``:
  the same on the wall clock, from ``/api/stats`` ``video`` (null for tiles; means of its last 240
  frames), with ``target_bitrate`` (bit/s) there at the end; ``keyframes``; ``frames_lost``;
* ``latency_intervals_p50``: input → decoded frame, p50, in mean intervals between decoded frames
  (and ``latency_p50_ms``), for the first decoded frame answering each input, as
  :func:`bench.live.latencies`;
* with ``--rest-s``: ``still_s`` (the still's arrival after the last input; null: it did not come),
  ``still_kb``, ``refinements_kb`` (the progressive still's frames that came before it),
  ``still_exact`` (equal to the coordinator's still of that frame, ``/api/frame.png?still=true``),
  ``still_psnr`` (against ``--render-once``'s still of the same camera, 100 = identical; null with
  synthetic nodes), ``resume_ms`` (moving again: the first answer's delay) and ``fps_resumed``.

``--synthetic``: no local nodes but ``--nodes`` synthetic ones (:mod:`bench.synthetic_nodes`,
default 4, 1920x1080, a fixed noisy gradient cut into every tile): for "1080p60 fits in 8 Mbit/s at
≥ 35 dB". Their pictures have no render-once reference, so there ``psnr_*`` is measured against the
coordinator's composite (``psnr_source_*``, the tiles the encoder was given). The coordinator gets
``--still-samples 1`` (unless ``--server-args`` names it): synthetic nodes ignore the jitter of a
progressive still's samples, so its samples would only be more frames of the same picture.

Everything shares this machine's cores (the viewer's decoding too).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import shlex
import sys
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import websockets.sync.client as ws_client
from PIL import Image

from bench.images import psnr, reported_psnr, viewer_frame_image
from bench.live import latencies, wait_ready
from bench.paths import KINDS, make_path, orbit_around, random_cameras, surface_focus
from bench.processes import PYTHON, LoggedProcess, show_result, start_coordinator
from bench.quality import camera_seed
from bench.stream_summary import summarize, summary_table
from bench.stream_viewer import StreamViewer
from bench.synthetic_nodes import SCENE_BOUNDS
from bench.throttle import throttled_proxy
from node.gl.context import create_gl_context
from node.gl.renderer import TileRenderer
from node.scene.data import SceneData
from node.scene.loading import load_scene
from node.settings import NodeSettings
from tessera.cli_values import size_parser
from tessera.geometry import Camera
from tessera.scheduling.refinement import ADAPTIVE, StillPlan
from tessera.wire.video import VideoCodec, codec_string

#: ``tiles`` and every video codec of the protocol
TRANSPORTS = ("tiles", *(codec.label for codec in VideoCodec))
#: seconds after the last input the viewer keeps reading (the answers still on their way)
TAIL_S = 1.0
SYNTHETIC_SIZE = (1920, 1080)
SYNTHETIC_NODES = 4


class PathPlayer:
    """A camera path ``{"dt_ms", "frames": [camera, …]}`` as a function of time: :meth:`at` gives
    the camera ``t`` s in, linearly between two of its frames (eye, target, up, fovy), looping."""

    def __init__(self, path: dict[str, Any]) -> None:
        self.dt_s = float(path["dt_ms"]) / 1000.0
        self.frames = list(path["frames"])

    def at(self, t: float) -> dict[str, Any]:
        position = t / self.dt_s
        index = int(position) % len(self.frames)
        a, b = self.frames[index], self.frames[(index + 1) % len(self.frames)]
        w = position - math.floor(position)
        camera = dict(a)
        for key in ("eye", "target", "up"):
            if key in a and key in b:
                camera[key] = ((1.0 - w) * np.asarray(a[key], float) + w * np.asarray(b[key], float)).tolist()
        if "fovy_deg" in a and "fovy_deg" in b:
            camera["fovy_deg"] = (1.0 - w) * a["fovy_deg"] + w * b["fovy_deg"]
        return camera


def load_path(spec: str, bounds: np.ndarray, positions: np.ndarray | None) -> dict[str, Any]:
    """The path JSON file ``spec``, or a :data:`bench.paths.KINDS` path for the scene ``bounds``
    (2, 3) (zoom: towards the vertex of ``positions`` (N, 3) nearest the default eye, or the centre)."""
    if spec not in KINDS:
        return json.loads(Path(spec).read_text())
    focus = surface_focus(positions, bounds) if positions is not None else None
    return make_path(spec, bounds, focus=focus)


def video_stats(stats: dict[str, Any], transport: str) -> dict[str, Any] | None:
    """The ``/api/stats`` ``video`` entry of the ``transport`` codec's stream, if any."""
    names = (transport, codec_string(VideoCodec.parse(transport), (16, 16)).split(".")[0])
    streams = [s for s in stats.get("video") or [] if str(s.get("codec", "")).lower().startswith(names)]
    return max(streams, key=lambda s: s.get("frames_encoded", 0)) if streams else None


def _move(viewer: StreamViewer, player: PathPlayer, input_hz: float, path_start: float, until: float) -> None:
    """Send the path's cameras at ``input_hz`` (the path's time counted from ``path_start``,
    perf_counter s) until ``until``; a video viewer reports each :data:`REPORT_S`."""
    next_send = time.perf_counter()
    while (now := time.perf_counter()) < until:
        viewer.send_camera(player.at(now - path_start))
        viewer.report_due(now)
        next_send += 1.0 / input_hz
        time.sleep(max(0.0, next_send - time.perf_counter()))


def _rest(args: argparse.Namespace, viewer: StreamViewer, client: httpx.Client, last_input: float) -> dict[str, Any]:
    """The camera rests from ``last_input``: wait (at most ``--rest-s``) for the still answering
    the last input and fetch the coordinator's still of that frame (``/api/frame.png``)."""
    still, source = None, None
    while time.perf_counter() < last_input + args.rest_s and still is None:
        time.sleep(0.02)
        viewer.report_due(time.perf_counter())
        with viewer.lock:
            still = next((s for s in viewer.stills if s[0] > last_input and s[2] == viewer.seq), None)
    if still is not None:
        response = client.get("/api/frame.png", params={"after": still[1], "still": "true", "timeout": 10})
        if response.status_code == 200 and int(response.headers["x-frame-id"]) == still[1]:
            source = np.asarray(Image.open(io.BytesIO(response.content)).convert("RGB"))
    return {"still": still, "still_source": source, "last_input": last_input, "camera": viewer.camera}


def play(args: argparse.Namespace, url: str, client: httpx.Client, transport: str,
         player: PathPlayer) -> dict[str, Any]:
    """One transport: a viewer offers it (through a link of ``--throttle-mbps``, if given), plays
    the path for ``--moving-s`` and reads on for :data:`TAIL_S`; with ``--rest-s``, then rests
    until the still comes and plays on for ``--resume-s``. The stopped viewer, the coordinator's
    answer, the window (perf_counter s: from 1 s after the first input to the last), the stream's
    ``video`` stats at its end, and the rest's still and window (:func:`_rest`)."""
    with contextlib.ExitStack() as stack:
        rate = args.throttle_mbps * 1e6 if args.throttle_mbps else None
        link = stack.enter_context(throttled_proxy(int(url.rsplit(":", 1)[1]), rate))
        ws_url = f"ws://127.0.0.1:{link.port}/ws/view"
        viewer = StreamViewer(stack.enter_context(ws_client.connect(ws_url, max_size=256 << 20)), transport, url)
        try:
            choice = viewer.offer()
            if choice.get("transport") != transport:
                return {"viewer": viewer, "choice": choice, "link": link}
            started = time.perf_counter()
            viewer.sample_every_s = (args.moving_s - 1.0) / args.psnr_frames
            viewer.sample_from = started + 1.0 + viewer.sample_every_s / 2.0
            _move(viewer, player, args.input_hz, started, started + args.moving_s)
            last_input = time.perf_counter()
            viewer.sample_from = math.inf
            time.sleep(TAIL_S)
            stream = video_stats(client.get("/api/stats").json(), transport) if transport != "tiles" else None
            rest = None
            if args.rest_s:
                rest = _rest(args, viewer, client, last_input)
                rest["resumed"], rest["resume_seq"] = time.perf_counter(), viewer.seq
                _move(viewer, player, args.input_hz, started, rest["resumed"] + args.resume_s)
                rest["resume_end"] = time.perf_counter()
                time.sleep(TAIL_S)
        finally:
            viewer.stop()
    return {"viewer": viewer, "choice": choice, "start": started + 1.0, "end": last_input, "stream": stream,
            "rest": rest, "link": link}


class References:
    """Reference frames of cameras: the interactive frame (one sample, not shifted) rendered whole
    by a node's renderer with a node's default settings, as ``python -m node --render-once
    --interactive`` renders it, in this process."""

    def __init__(self, scene: SceneData, size: tuple[int, int]) -> None:
        settings = NodeSettings(scene="", size=size)
        self.size = size
        self.state = scene.state_at(0.0)
        self.ctx = create_gl_context()
        self.renderer = TileRenderer(self.ctx, scene, settings.background, culling=settings.culling,
                                     shading=settings.shading)

    def image(self, camera: dict[str, Any]) -> np.ndarray:
        """(h, w, 3) uint8."""
        return self.renderer.render_frame(Camera.from_json(camera), self.size, self.state).pixels

    def still(self, camera: dict[str, Any], plan: StillPlan) -> np.ndarray:
        """The converged still sampled as ``plan`` says (``--render-once``), (h, w, 3) uint8."""
        return self.renderer.render_still(Camera.from_json(camera), self.size, plan, self.state)

    def release(self) -> None:
        self.renderer.release()
        self.ctx.release()


def compare(image: np.ndarray, reference: np.ndarray) -> float:
    """PSNR (dB, :func:`bench.images.psnr`) over the region both images cover (a decoder may
    return a frame padded to its block size)."""
    h, w = min(image.shape[0], reference.shape[0]), min(image.shape[1], reference.shape[1])
    return psnr(image[:h, :w], reference[:h, :w])


def psnr_figures(values: list[float], prefix: str) -> dict[str, Any]:
    """``{prefix}_mean``, ``{prefix}_min`` and ``{prefix}_frames`` of PSNRs in dB (100: identical;
    the mean of identical frames is 100 too)."""
    reported = [reported_psnr(v) for v in values]
    return {f"{prefix}_mean": round(float(np.mean(reported)), 2) if reported else None,
            f"{prefix}_min": min(reported) if reported else None, f"{prefix}_frames": len(reported)}


def still_plan_of(stats: dict[str, Any]) -> StillPlan:
    """How the coordinator samples its still, from ``/api/stats``' ``still_samples``."""
    figures = stats.get("still_samples") or {}
    wanted = int(figures.get("wanted") or 1)
    if figures.get("adaptive"):
        return StillPlan(ADAPTIVE, wanted, float(figures["target_db"]))
    return StillPlan(wanted)


def rest_figures(run: dict[str, Any], references: References | None, plan: StillPlan) -> dict[str, Any]:
    """The rest's figures (``--rest-s``): the still's arrival after the last input (s), its size
    (KB) and the refinements' before it, whether it equals the coordinator's still of that frame
    (``/api/frame.png``) and its PSNR against render-once's still sampled as ``plan`` says; then,
    moving again, the first answer's delay (ms) and the frames decoded per second."""
    rest, viewer = run["rest"], run["viewer"]
    still = rest["still"]
    arrived = still[0] if still is not None else rest["resumed"]
    with viewer.lock:
        refinements = sum(size for at, size in viewer.refinements if rest["last_input"] < at <= arrived)
        decoded = [f for f in viewer.decoded if rest["resumed"] <= f["at"] <= rest["resume_end"]]
        answers = [f["at"] for f in viewer.decoded if f["at"] >= rest["resumed"] and f["input"] > rest["resume_seq"]]
    out: dict[str, Any] = {"still_s": None, "still_kb": None, "still_exact": None, "still_psnr": None,
                           "refinements_kb": round(refinements / 1000, 1)}
    if still is not None:
        image = viewer_frame_image(still[3])
        out.update({"still_s": round(still[0] - rest["last_input"], 3), "still_kb": round(len(still[3]) / 1000, 1),
                    "still_exact": rest["still_source"] is not None and np.array_equal(image, rest["still_source"])})
        if references is not None:
            out["still_psnr"] = reported_psnr(compare(image, references.still(rest["camera"], plan)))
    out["resume_ms"] = round((answers[0] - rest["resumed"]) * 1000.0, 1) if answers else None
    out["fps_resumed"] = round(len(decoded) / (rest["resume_end"] - rest["resumed"]), 2)
    return out


def figures(run: dict[str, Any], references: References | None) -> dict[str, Any]:
    """One transport's figures from what its viewer decoded (see the module docstring)."""
    viewer: StreamViewer = run["viewer"]
    choice = run["choice"]
    out: dict[str, Any] = {"transport": choice.get("transport"), "codec": choice.get("codec"),
                           "reason": choice.get("reason")}
    if "start" not in run:
        return out
    start, end = run["start"], run["end"]
    with viewer.lock:
        decoded = list(viewer.decoded)
        samples = {i: (viewer.samples[i], viewer.sample_inputs[i]) for i in viewer.samples}
        sources = dict(viewer.sources)
    window = [f for f in decoded if start <= f["at"] <= end]
    seconds = end - start
    fps = len(window) / seconds
    intervals = np.diff([f["at"] for f in window])
    interval_ms = float(intervals.mean() * 1000.0) if len(intervals) else math.nan
    lat = latencies([f for f in decoded if start <= f["at"] <= end + TAIL_S],
                    {k: v for k, v in viewer.sent.items() if start <= v <= end})
    p50 = float(np.percentile(lat, 50)) if lat else math.nan
    bytes_per_frame = float(np.mean([f["bytes"] for f in window])) if window else math.nan
    wire_per_frame = run["link"].bytes_between(start, end) / len(window) if window else math.nan
    against_render = [compare(image, references.image(viewer.cameras[seq]))
                      for image, seq in samples.values() if seq in viewer.cameras] if references else []
    against_source = [compare(image, sources[i]) for i, (image, _) in samples.items() if i in sources]
    stream = run["stream"] or {}
    sizes = {tuple(image.shape[1::-1]) for image, _ in samples.values()}
    out.update({
        "frames": len(window), "fps": round(fps, 2), "bytes_per_frame": round(bytes_per_frame, 1),
        "mbps": round(bytes_per_frame * 8.0 * fps / 1e6, 3),
        "mbps_at_60fps": round(bytes_per_frame * 8.0 * 60.0 / 1e6, 3),
        "wire_bytes_per_frame": round(wire_per_frame, 1), "wire_mbps": round(wire_per_frame * 8.0 * fps / 1e6, 3),
        "viewer_decode_ms": round(float(np.mean([f["decode_ms"] for f in window])), 2) if window else None,
        **psnr_figures(against_render if references else against_source, "psnr"),
        **psnr_figures(against_source, "psnr_source"),
        "psnr_reference": "render-once" if references else "frame.png",
        "decoded_size": [list(s) for s in sorted(sizes)],
        "encode_ms": stream.get("encode_cpu_ms_mean") if run["stream"] else None,
        "encode_ms_p50": stream.get("encode_cpu_ms_p50"), "compose_ms": stream.get("compose_cpu_ms_mean"),
        "encode_wall_ms": stream.get("encode_ms_mean"), "compose_wall_ms": stream.get("compose_ms_mean"),
        "frames_encoded": stream.get("frames_encoded"), "target_bitrate": stream.get("bitrate"),
        "crf": stream.get("crf"), "crf_changes": stream.get("crf_changes"),
        "psnr_video_measured": stream.get("psnr_video_db"), "psnr_tiles_measured": stream.get("psnr_tiles_db"),
        "keyframes": viewer.keyframes, "frames_lost": viewer.lost, "tile_frames_after_choice":
        viewer.tfrm_after_choice if choice.get("transport") != "tiles" else None,
        "frame_interval_ms": round(interval_ms, 2), "latency_p50_ms": round(p50, 1),
        "latency_intervals_p50": round(p50 / interval_ms, 2) if interval_ms else None,
        "latency_samples": len(lat),
    })
    return out


def camera_paths(args: argparse.Namespace, bounds: np.ndarray, positions: np.ndarray | None,
                 size: tuple[int, int]) -> list[tuple[str, dict[str, Any]]]:
    """(name, camera path) pairs to play at ``size``: ``--path``, or with ``--cameras N`` an orbit
    (:func:`bench.paths.orbit_around`) from each of N random cameras around the scene
    (:func:`bench.paths.random_cameras`, from ``--seed`` and the scene's name, framed for ``size``'s aspect)."""
    if not args.cameras:
        return [(args.path, load_path(args.path, bounds, positions))]
    cameras = random_cameras(bounds, args.cameras, camera_seed(args.scene, args.seed), aspect=size[0] / size[1])
    return [(f"camera {i}", orbit_around(camera)) for i, camera in enumerate(cameras)]


def measure_size(args: argparse.Namespace, size: tuple[int, int], scene: SceneData | None, bounds: np.ndarray,
                 positions: np.ndarray | None) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """Start the service at ``size``, play every transport along each camera path, stop it, then
    measure the samples' PSNR: one run per path (``size``, ``camera``, ``transports``: figures per
    transport), and what the service said of itself (still samples, renderer)."""
    server_args = ["--size", f"{size[0]}x{size[1]}"]
    if not args.synthetic:
        server_args += ["--local-nodes", str(args.nodes), "--scene", args.scene]
    extra = shlex.split(args.server_args)
    if args.synthetic and "--still-samples" not in extra:
        server_args += ["--still-samples", "1"]
    if "--stream" not in extra and any(t != "tiles" for t in args.transports):
        server_args += ["--stream", "auto"]
    played: list[tuple[str, dict[str, dict[str, Any]]]] = []
    coordinator, url = start_coordinator([*server_args, *extra], log_level="warning")
    synthetic: LoggedProcess | None = None
    try:
        if args.synthetic:
            synthetic = LoggedProcess([PYTHON, "-m", "bench.synthetic_nodes", "--url",
                                       url.replace("http://", "ws://", 1) + "/ws/node", "--nodes", str(args.nodes)])
        with httpx.Client(base_url=url, timeout=120) as client:
            stats = wait_ready(client, args.nodes)
            still_plan = still_plan_of(stats)
            for name, path in camera_paths(args, bounds, positions, size):
                player = PathPlayer(path)
                played.append((name, {t: play(args, url, client, t, player) for t in args.transports}))
    finally:
        if synthetic is not None:
            synthetic.stop()
        coordinator.stop(timeout=30.0)
    references = References(scene, size) if scene is not None else None
    runs = []
    try:
        for name, transports in played:
            result: dict[str, Any] = {t: figures(run, references) for t, run in transports.items()}
            for transport, run in transports.items():
                if run.get("rest") is not None:
                    result[transport].update(rest_figures(run, references, still_plan))
            runs.append({"size": list(size), "camera": name, "transports": result})
    finally:
        if references is not None:
            references.release()
    return runs, {"still_samples": "auto" if still_plan.adaptive else still_plan.samples,
                  "renderer": stats["nodes"][0]["renderer"]}


def measure(args: argparse.Namespace) -> dict[str, Any]:
    """Every size's runs (:func:`measure_size`): one run's figures keyed by transport, or with more
    runs (``--cameras``, ``--sizes``) each run's under ``runs``, their means and worst cases keyed by
    transport and under ``summary`` per size (:func:`bench.stream_summary.summarize`)."""
    scene: SceneData | None = None
    if args.synthetic:
        bounds, positions = np.asarray(SCENE_BOUNDS, dtype=float), None
    else:
        scene = load_scene(args.scene)
        bounds = scene.bounds
        positions = np.concatenate([b.positions for b in scene.batches]).astype(np.float64)
    runs: list[dict[str, Any]] = []
    for size in args.sizes:
        size_runs, service = measure_size(args, size, scene, bounds, positions)
        runs += size_runs
    meta = {"scene": "synthetic" if args.synthetic else args.scene, "path": args.path,
            "size": list(args.sizes[0]), "sizes": [list(size) for size in args.sizes], "cameras": args.cameras,
            "seed": args.seed, "nodes": args.nodes, "synthetic": args.synthetic,
            "input_hz": args.input_hz, "moving_s": args.moving_s, "server_args": args.server_args,
            "throttle_mbps": args.throttle_mbps, "rest_s": args.rest_s, "resume_s": args.resume_s, **service}
    if len(runs) == 1:
        return {**runs[0]["transports"], "run": meta}
    return {**summarize(runs), "runs": runs, "summary": {f"{w}x{h}": summarize([r for r in runs if r["size"] == [w, h]])
                                                         for w, h in args.sizes}, "run": meta}


def cell(value: float | None, width: int, places: int) -> str:
    """``value`` right-aligned in ``width`` with ``places`` decimals; '-' for None or NaN."""
    return f"{'-':>{width}}" if value is None or math.isnan(value) else f"{value:>{width}.{places}f}"


def _sum(*values: float | None) -> float | None:
    """The sum of ``values``, None when one is missing."""
    return None if any(v is None for v in values) else sum(v for v in values if v is not None)


def report(result: dict[str, Any]) -> str:
    run = result["run"]
    sizes = ", ".join(f"{w}x{h}" for w, h in run["sizes"])
    paths = (f"orbits from {run['cameras']} random cameras (seed {run['seed']})" if run["cameras"]
             else f"path {run['path']}")
    lines = [f"Tessera stream benchmark: {run['scene']} at {sizes}, {run['nodes']} "
             f"{'synthetic' if run['synthetic'] else 'local'} nodes ({run['renderer']}), {paths} "
             f"with input at {run['input_hz']:g} Hz for {run['moving_s']:g} s per transport"
             + (f", server args {run['server_args']!r}" if run["server_args"] else "")
             + (f", link {run['throttle_mbps']:g} Mbit/s" if run["throttle_mbps"] else "")]
    for one in result.get("runs") or [{"transports": result}]:
        if "size" in one:
            lines.append(f"{one['size'][0]}x{one['size'][1]}, {one['camera']}:")
        lines += transport_rows(one["transports"])
    reference = ("render-once of each sampled frame's camera" if not run["synthetic"]
                 else "the coordinator's composite of the same frame (GET /api/frame.png)")
    lines.append("KB/frame: messages, wire: on the wire (permessage-deflate); "
                 f"PSNR against {reference}; 'vs src': against the coordinator's composite of the tiles "
                 "(the encoder's source); enc/comp ms: the coordinator's CPU per frame (its stream thread), "
                 "wall: both on the wall clock; dec ms: this "
                 "viewer's CPU per frame; latency: input to decoded frame, in frame intervals (ms); crf: the "
                 "H.264 stream's at the end, with the coordinator's own PSNR of the video and the tiles' JPEG")
    if "summary" in result:
        lines += summary_table(result["summary"])
    return "\n".join(lines)


def transport_rows(result: dict[str, Any]) -> list[str]:
    """The table of one run's figures keyed by transport."""
    lines = [f"{'transport':<10}{'KB/frame':>9}{'wire':>6}{'Mbit/s':>8}{'@60fps':>8}{'fps':>6}{'PSNR mean':>10}"
             f"{'min':>7}{'vs src':>8}{'enc ms':>8}{'comp ms':>8}{'wall':>6}{'dec ms':>8}{'latency p50':>19}"
             f"{'keys':>5}{'lost':>5}{'crf':>7}{'own video/tiles dB':>20}"]
    for transport in TRANSPORTS:
        row = result.get(transport)
        if row is None:
            continue
        if "fps" not in row:
            lines.append(f"{transport:<10}not streamed: the coordinator chose {row['transport']} "
                         f"({row['reason'] or 'no reason given'})")
            continue
        lines.append(f"{transport:<10}{cell(row['bytes_per_frame'] / 1000, 9, 1)}"
                     f"{cell(row['wire_bytes_per_frame'] / 1000, 6, 1)}{cell(row['mbps'], 8, 2)}"
                     f"{cell(row['mbps_at_60fps'], 8, 2)}{cell(row['fps'], 6, 1)}{cell(row['psnr_mean'], 10, 2)}"
                     f"{cell(row['psnr_min'], 7, 2)}{cell(row['psnr_source_mean'], 8, 2)}"
                     f"{cell(row['encode_ms'], 8, 2)}{cell(row['compose_ms'], 8, 2)}"
                     f"{cell(_sum(row.get('encode_wall_ms'), row.get('compose_wall_ms')), 6, 1)}"
                     f"{cell(row['viewer_decode_ms'], 8, 2)}{cell(row['latency_intervals_p50'], 8, 2)} "
                     f"({cell(row['latency_p50_ms'], 5, 0)} ms){row['keyframes']:>5}{row['frames_lost']:>5}"
                     f"{cell(row.get('crf'), 7, 2)}{cell(row.get('psnr_video_measured'), 11, 2)}"
                     f"{cell(row.get('psnr_tiles_measured'), 9, 2)}")
    for transport in TRANSPORTS:
        row = result.get(transport)
        if row is not None and "still_s" in row:
            lines.append(f"{transport:<10}rest: still after {cell(row['still_s'], 5, 2)} s "
                         f"({cell(row['still_kb'], 6, 1)} KB, refinements before it {row['refinements_kb']:.1f} KB), "
                         f"exact: {row['still_exact']}, "
                         f"PSNR vs render-once still {cell(row['still_psnr'], 6, 2)}; moving again: first answer "
                         f"{cell(row['resume_ms'], 6, 0)} ms, {cell(row['fps_resumed'], 5, 1)} fps")
    return lines


def sizes_parser(text: str) -> list[tuple[int, int]]:
    """``--sizes``: comma-separated WxH."""
    one = size_parser(16, 8192)
    return [one(part.strip()) for part in text.split(",") if part.strip()]


def parse_transports(text: str) -> list[str]:
    names = [part.strip().lower() for part in text.split(",") if part.strip()]
    if not names or any(name not in TRANSPORTS for name in names):
        raise argparse.ArgumentTypeError(f"transports are some of {', '.join(TRANSPORTS)}, got {text!r}")
    return names


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m bench.stream", description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="builtin:cluster")
    parser.add_argument("--path", default="orbit",
                        help=f"camera path JSON (bench/paths/*.json) or one of {', '.join(KINDS)} (default orbit)")
    parser.add_argument("--size", type=size_parser(16, 8192),
                        help="WxH (default 1280x720; with --synthetic 1920x1080)")
    parser.add_argument("--sizes", type=sizes_parser, help="WxH,WxH,...: a run at each size (instead of --size)")
    parser.add_argument("--cameras", type=int, default=0,
                        help="play an orbit from each of N random cameras around the scene instead of --path")
    parser.add_argument("--seed", type=int, default=0, help="the random cameras' seed (default 0)")
    parser.add_argument("--nodes", type=int, help=f"local nodes (default 3; with --synthetic {SYNTHETIC_NODES})")
    parser.add_argument("--moving-s", type=float, default=8.0, help="seconds of camera motion per transport")
    parser.add_argument("--input-hz", type=float, default=60.0, help="camera messages per second (default 60)")
    parser.add_argument("--transports", type=parse_transports, default=list(TRANSPORTS),
                        help="comma-separated, of " + ",".join(TRANSPORTS))
    parser.add_argument("--psnr-frames", type=int, default=8, help="decoded frames sampled for PSNR per transport")
    parser.add_argument("--synthetic", action="store_true",
                        help="synthetic nodes (bench.synthetic_nodes) instead of local ones; PSNR against the "
                             "coordinator's composite")
    parser.add_argument("--server-args", default="", help="more flags for python -m server")
    parser.add_argument("--throttle-mbps", type=float,
                        help="each viewer's link: a loopback proxy passing the coordinator's bytes at this Mbit/s")
    parser.add_argument("--rest-s", type=float, default=0.0,
                        help="after the moving window, rest up to this long for the still, then move again")
    parser.add_argument("--resume-s", type=float, default=3.0, help="seconds of motion after the rest (default 3)")
    parser.add_argument("--json", type=Path, help="write the figures here")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    args.sizes = args.sizes or [args.size or (SYNTHETIC_SIZE if args.synthetic else (1280, 720))]
    args.nodes = args.nodes or (SYNTHETIC_NODES if args.synthetic else 3)
    if args.moving_s <= 1.0 or args.psnr_frames < 1:
        raise SystemExit("--moving-s must exceed 1 s and --psnr-frames be >= 1")
    if args.cameras < 0 or (args.cameras and args.synthetic):
        raise SystemExit("--cameras must be >= 0, and synthetic nodes draw no cameras")
    result = measure(args)
    show_result(report(result), result, args.json, argv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
