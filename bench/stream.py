"""Video to the browser (issue 21): a camera path played through the live service once per transport
(tiles, then each codec of :class:`tessera.wire.video.VideoCodec`), each watched by a scripted
viewer that decodes what it receives.

``python -m bench.stream [--scene S] [--path P] [--size WxH] [--nodes N] [--moving-s 8]
[--input-hz 60] [--transports tiles,h264,vp9] [--psnr-frames 8] [--synthetic]
[--server-args "…"] [--json OUT]``

One coordinator (``python -m server --local-nodes N --stream auto``, as :mod:`bench.live` starts
it) serves every transport in turn: per transport a new viewer on ``/ws/view`` sends
``stream_offer`` with only that codec (tiles: none) and checks the ``stream`` answer, then sends
cameras with input numbers at ``--input-hz`` for ``--moving-s``: the camera path ``--path`` (a
``bench/paths/*.json`` file, or a kind of :func:`bench.paths.make_path` made for the scene's
bounds, loaded here; synthetic nodes': their box) played at its own ``dt_ms``, cameras between two
of its frames interpolated, looping. A video viewer sends ``stream_report`` each second, as
``web/video.js`` does. The viewer's reader thread decodes every interactive frame as it comes:
TFRM tiles with :func:`bench.images.viewer_frame_image`, TVID access units with PyAV
(``av.CodecContext.create(codec, "r")``, one ``av.Packet`` each; a unit that fails to decode, or
any unit after one until a keyframe, is lost, and the viewer then sends ``keyframe``).

Figures per transport, over the moving window (its first second left out):

* ``fps``: interactive frames decoded per second; ``bytes_per_frame``: mean message size on the
  socket (header included); ``mbps``: ``bytes_per_frame`` × 8 × ``fps``; ``mbps_at_60fps``: at
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
  :func:`bench.live.latencies`.

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
import io
import json
import math
import queue
import shlex
import sys
import threading
import time
from pathlib import Path
from typing import Any

import av
import httpx
import numpy as np
import websockets.sync.client as ws_client
from PIL import Image

from bench.images import psnr, reported_psnr, viewer_frame_image
from bench.live import ScriptedViewer, latencies, wait_ready
from bench.paths import KINDS, make_path, surface_focus
from bench.processes import PYTHON, LoggedProcess, show_result, start_coordinator
from bench.synthetic_nodes import SCENE_BOUNDS
from node.gl.context import create_gl_context
from node.gl.renderer import TileRenderer
from node.scene.data import SceneData
from node.scene.loading import load_scene
from node.settings import NodeSettings
from tessera.cli_values import size_parser
from tessera.geometry import Camera
from tessera.wire.protocol import unpack_frame
from tessera.wire.stream_messages import KeyframeRequest, StreamOffer, StreamReport
from tessera.wire.video import VideoCodec, codec_string, is_video, unpack_video

#: ``tiles`` and every video codec of the protocol
TRANSPORTS = ("tiles", *(codec.label for codec in VideoCodec))
#: seconds a viewer waits for the coordinator's ``stream`` answer to its offer
CHOICE_TIMEOUT_S = 10.0
#: seconds after the last input the viewer keeps reading (the answers still on their way)
TAIL_S = 1.0
#: seconds between two ``stream_report`` s of a video viewer (as web/video.js)
REPORT_S = 1.0
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


class StreamViewer(ScriptedViewer):
    """A :class:`bench.live.ScriptedViewer` that offers ``transport`` and decodes what it gets.

    ``decoded``: per interactive frame decoded, its time (perf_counter s), frame id, message bytes,
    input number and keyframe flag; ``lost``: video frames that did not decode; ``samples``: the
    decoded images (h, w, 3) of frames taken for PSNR (one each ``sample_every_s`` from
    ``sample_from`` on), keyed by frame id, with their input numbers in ``sample_inputs``;
    ``sources``: those frames' composites from ``/api/frame.png`` when ``http`` is given."""

    def __init__(self, ws: ws_client.ClientConnection, transport: str, http_url: str | None) -> None:
        self.transport = transport
        self.choice: dict[str, Any] | None = None
        self._chosen = threading.Event()
        self.decoded: list[dict[str, Any]] = []
        self.lost = 0
        self.keyframes = 0
        self.tfrm_after_choice = 0
        self.samples: dict[int, np.ndarray] = {}
        self.sample_inputs: dict[int, int] = {}
        self.sources: dict[int, np.ndarray] = {}
        self.cameras: dict[int, dict[str, Any]] = {}
        self.newest_video: int | None = None
        self.sample_from = math.inf
        self.sample_every_s = math.inf
        self._decoder: Any = None
        self._waiting_for_key = True
        self._fetches: queue.Queue[int | None] = queue.Queue()
        self._fetcher = threading.Thread(target=self._fetch_sources, args=(http_url,), daemon=True) \
            if http_url is not None else None
        super().__init__(ws)
        if self._fetcher is not None:
            self._fetcher.start()

    def offer(self) -> dict[str, Any]:
        """Send ``stream_offer`` with this viewer's codec (tiles: none) and wait for the answer
        (tiles: up to :data:`CHOICE_TIMEOUT_S`, then go on with tiles without one)."""
        codecs = () if self.transport == "tiles" else (self.transport,)
        if self.transport != "tiles":
            self._decoder = av.CodecContext.create(self.transport, "r")
        self.ws.send(StreamOffer(codecs=codecs).to_text())
        if not self._chosen.wait(CHOICE_TIMEOUT_S):
            if self.transport == "tiles":   # a coordinator without video streams sends tiles anyway
                return {"type": "stream", "transport": "tiles", "reason": "no answer to the offer"}
            raise RuntimeError(f"no 'stream' answer to the offer of {list(codecs)} within {CHOICE_TIMEOUT_S:.0f} s")
        assert self.choice is not None
        return self.choice

    def send_camera(self, camera: dict[str, Any]) -> None:
        super().send_camera(camera)
        self.cameras[self.seq] = camera

    def counts(self) -> tuple[float, int, int]:
        """Now (perf_counter s), bytes received and frames decoded so far."""
        with self.lock:
            return time.perf_counter(), sum(f["bytes"] for f in self.decoded), len(self.decoded)

    def report(self, since: tuple[float, int, int]) -> tuple[float, int, int]:
        """Send ``stream_report`` (as a browser viewer does each second) over the window since
        ``since`` (:meth:`counts` then); the next window's start."""
        now = self.counts()
        seconds = max(now[0] - since[0], 1e-3)
        self.ws.send(StreamReport(bytes_per_s=(now[1] - since[1]) / seconds, decoded_fps=(now[2] - since[2]) / seconds,
                                  decode_queue=0, frames_dropped=self.lost, frame=self.newest_video).to_text())
        return now

    def _read(self) -> None:
        while not self._stop.is_set():
            try:
                message = self.ws.recv(timeout=0.2)
            except TimeoutError:
                continue
            except Exception:
                return
            if isinstance(message, str):
                control = json.loads(message)
                if control.get("type") == "stream":
                    self.choice = control
                    self._chosen.set()
            elif is_video(message):
                self._on_video(message)
            else:
                self._on_tiles(message)

    def _on_tiles(self, message: bytes) -> None:
        frame = unpack_frame(message)
        if frame.still or frame.samples:   # the still and its progressive refinements
            return
        if self.choice is not None:
            self.tfrm_after_choice += 1
        started = time.thread_time()
        image = viewer_frame_image(message)
        decode_ms = (time.thread_time() - started) * 1000.0
        self._record(frame.frame_id, len(message), frame.input_seq, False, image, decode_ms)

    def _on_video(self, message: bytes) -> None:
        frame = unpack_video(message)
        self.newest_video = frame.frame_id
        self.keyframes += frame.keyframe
        assert self._decoder is not None, "a video frame before the offer"
        if self._waiting_for_key and not frame.keyframe:
            self.lost += 1
            return
        packet = av.Packet(frame.data)
        packet.pts = frame.frame_id
        started = time.thread_time()
        try:
            pictures = self._decoder.decode(packet)
        except av.error.FFmpegError:
            pictures = []
        decode_ms = (time.thread_time() - started) * 1000.0
        if not pictures:
            self.lost += 1
            self._waiting_for_key = True
            self.ws.send(KeyframeRequest().to_text())
            return
        self._waiting_for_key = False
        for picture in pictures:
            self._record(frame.frame_id, len(message), frame.input_seq, frame.keyframe, picture, decode_ms)

    def _record(self, frame_id: int, size: int, input_seq: int, keyframe: bool, image: Any,
                decode_ms: float) -> None:
        """Note a decoded frame (``decode_ms``: this thread's CPU decoding it); keep its pixels (an
        ndarray or an ``av.VideoFrame``) when sampled."""
        now = time.perf_counter()
        with self.lock:
            self.decoded.append({"at": now, "id": frame_id, "bytes": size, "input": input_seq,
                                 "keyframe": keyframe, "decode_ms": decode_ms})
        if now >= self.sample_from:
            self.sample_from += self.sample_every_s
            pixels = image if isinstance(image, np.ndarray) else image.to_ndarray(format="rgb24")
            with self.lock:
                self.samples[frame_id] = pixels
                self.sample_inputs[frame_id] = input_seq
            self._fetches.put(frame_id)

    def _fetch_sources(self, url: str) -> None:
        """The composites of the sampled frames, fetched as they are sampled (the coordinator keeps
        its newest 16 frames): a frame it no longer holds is left out."""
        with httpx.Client(base_url=url, timeout=30) as client:
            while (frame_id := self._fetches.get()) is not None:
                response = client.get("/api/frame.png", params={"after": frame_id, "timeout": 5})
                if response.status_code == 200 and int(response.headers["x-frame-id"]) == frame_id:
                    image = np.asarray(Image.open(io.BytesIO(response.content)).convert("RGB"))
                    with self.lock:
                        self.sources[frame_id] = image

    def stop(self) -> None:
        super().stop()
        if self._fetcher is not None:
            self._fetches.put(None)
            self._fetcher.join(timeout=30)


def video_stats(stats: dict[str, Any], transport: str) -> dict[str, Any] | None:
    """The ``/api/stats`` ``video`` entry of the ``transport`` codec's stream, if any."""
    names = (transport, codec_string(VideoCodec.parse(transport), (16, 16)).split(".")[0])
    streams = [s for s in stats.get("video") or [] if str(s.get("codec", "")).lower().startswith(names)]
    return max(streams, key=lambda s: s.get("frames_encoded", 0)) if streams else None


def play(args: argparse.Namespace, url: str, client: httpx.Client, transport: str,
         player: PathPlayer) -> dict[str, Any]:
    """One transport: a viewer offers it, plays the path for ``--moving-s`` and reads on for
    :data:`TAIL_S`; the stopped viewer, the coordinator's answer, the window (perf_counter s: from
    1 s after the first input to the last) and the stream's ``video`` stats at the end."""
    ws_url = url.replace("http://", "ws://") + "/ws/view"
    with ws_client.connect(ws_url, max_size=256 << 20) as ws:
        viewer = StreamViewer(ws, transport, url)
        try:
            choice = viewer.offer()
            if choice.get("transport") != transport:
                return {"viewer": viewer, "choice": choice}
            started = next_send = time.perf_counter()
            window = viewer.counts()
            viewer.sample_every_s = (args.moving_s - 1.0) / args.psnr_frames
            viewer.sample_from = started + 1.0 + viewer.sample_every_s / 2.0
            while (now := time.perf_counter()) < started + args.moving_s:
                viewer.send_camera(player.at(now - started))
                if transport != "tiles" and now >= window[0] + REPORT_S:
                    window = viewer.report(window)
                next_send += 1.0 / args.input_hz
                time.sleep(max(0.0, next_send - time.perf_counter()))
            last_input = time.perf_counter()
            viewer.sample_from = math.inf
            time.sleep(TAIL_S)
            stream = video_stats(client.get("/api/stats").json(), transport) if transport != "tiles" else None
        finally:
            viewer.stop()
    return {"viewer": viewer, "choice": choice, "start": started + 1.0, "end": last_input, "stream": stream}


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
    against_render = [compare(image, references.image(viewer.cameras[seq]))
                      for image, seq in samples.values() if seq in viewer.cameras] if references else []
    against_source = [compare(image, sources[i]) for i, (image, _) in samples.items() if i in sources]
    stream = run["stream"] or {}
    sizes = {tuple(image.shape[1::-1]) for image, _ in samples.values()}
    out.update({
        "frames": len(window), "fps": round(fps, 2), "bytes_per_frame": round(bytes_per_frame, 1),
        "mbps": round(bytes_per_frame * 8.0 * fps / 1e6, 3),
        "mbps_at_60fps": round(bytes_per_frame * 8.0 * 60.0 / 1e6, 3),
        "viewer_decode_ms": round(float(np.mean([f["decode_ms"] for f in window])), 2) if window else None,
        **psnr_figures(against_render if references else against_source, "psnr"),
        **psnr_figures(against_source, "psnr_source"),
        "psnr_reference": "render-once" if references else "frame.png",
        "decoded_size": [list(s) for s in sorted(sizes)],
        "encode_ms": stream.get("encode_cpu_ms_mean") if run["stream"] else None,
        "encode_ms_p50": stream.get("encode_cpu_ms_p50"), "compose_ms": stream.get("compose_cpu_ms_mean"),
        "encode_wall_ms": stream.get("encode_ms_mean"), "compose_wall_ms": stream.get("compose_ms_mean"),
        "frames_encoded": stream.get("frames_encoded"), "target_bitrate": stream.get("bitrate"),
        "keyframes": viewer.keyframes, "frames_lost": viewer.lost, "tile_frames_after_choice":
        viewer.tfrm_after_choice if choice.get("transport") != "tiles" else None,
        "frame_interval_ms": round(interval_ms, 2), "latency_p50_ms": round(p50, 1),
        "latency_intervals_p50": round(p50 / interval_ms, 2) if interval_ms else None,
        "latency_samples": len(lat),
    })
    return out


def measure(args: argparse.Namespace) -> dict[str, Any]:
    """Start the service, play every transport, stop it, then measure the samples' PSNR."""
    scene: SceneData | None = None
    if args.synthetic:
        bounds, positions = np.asarray(SCENE_BOUNDS, dtype=float), None
        server_args = ["--size", f"{args.size[0]}x{args.size[1]}"]
    else:
        scene = load_scene(args.scene)
        bounds = scene.bounds
        positions = np.concatenate([b.positions for b in scene.batches]).astype(np.float64)
        server_args = ["--local-nodes", str(args.nodes), "--scene", args.scene, "--size",
                       f"{args.size[0]}x{args.size[1]}"]
    extra = shlex.split(args.server_args)
    if args.synthetic and "--still-samples" not in extra:
        server_args += ["--still-samples", "1"]
    if "--stream" not in extra and any(t != "tiles" for t in args.transports):
        server_args += ["--stream", "auto"]
    player = PathPlayer(load_path(args.path, bounds, positions))
    runs: dict[str, dict[str, Any]] = {}
    coordinator, url = start_coordinator([*server_args, *extra], log_level="warning")
    synthetic: LoggedProcess | None = None
    try:
        if args.synthetic:
            synthetic = LoggedProcess([PYTHON, "-m", "bench.synthetic_nodes", "--url",
                                       url.replace("http://", "ws://", 1) + "/ws/node", "--nodes", str(args.nodes)])
        with httpx.Client(base_url=url, timeout=120) as client:
            stats = wait_ready(client, args.nodes)
            for transport in args.transports:
                runs[transport] = play(args, url, client, transport, player)
    finally:
        if synthetic is not None:
            synthetic.stop()
        coordinator.stop(timeout=30.0)
    references = References(scene, args.size) if scene is not None else None
    try:
        result: dict[str, Any] = {t: figures(run, references) for t, run in runs.items()}
    finally:
        if references is not None:
            references.release()
    result["run"] = {"scene": "synthetic" if args.synthetic else args.scene, "path": args.path,
                     "size": list(args.size), "nodes": args.nodes, "synthetic": args.synthetic,
                     "input_hz": args.input_hz, "moving_s": args.moving_s, "server_args": args.server_args,
                     "renderer": stats["nodes"][0]["renderer"]}
    return result


def cell(value: float | None, width: int, places: int) -> str:
    """``value`` right-aligned in ``width`` with ``places`` decimals; '-' for None or NaN."""
    return f"{'-':>{width}}" if value is None or math.isnan(value) else f"{value:>{width}.{places}f}"


def _sum(*values: float | None) -> float | None:
    """The sum of ``values``, None when one is missing."""
    return None if any(v is None for v in values) else sum(v for v in values if v is not None)


def report(result: dict[str, Any]) -> str:
    run = result["run"]
    lines = [f"Tessera stream benchmark: {run['scene']} at {run['size'][0]}x{run['size'][1]}, {run['nodes']} "
             f"{'synthetic' if run['synthetic'] else 'local'} nodes ({run['renderer']}), path {run['path']} "
             f"with input at {run['input_hz']:g} Hz for {run['moving_s']:g} s per transport"
             + (f", server args {run['server_args']!r}" if run["server_args"] else ""),
             f"{'transport':<10}{'KB/frame':>9}{'Mbit/s':>8}{'@60fps':>8}{'fps':>6}{'PSNR mean':>10}{'min':>7}"
             f"{'vs src':>8}{'enc ms':>8}{'comp ms':>8}{'wall':>6}{'dec ms':>8}{'latency p50':>19}"
             f"{'keys':>5}{'lost':>5}"]
    for transport in TRANSPORTS:
        row = result.get(transport)
        if row is None:
            continue
        if "fps" not in row:
            lines.append(f"{transport:<10}not streamed: the coordinator chose {row['transport']} "
                         f"({row['reason'] or 'no reason given'})")
            continue
        lines.append(f"{transport:<10}{cell(row['bytes_per_frame'] / 1000, 9, 1)}{cell(row['mbps'], 8, 2)}"
                     f"{cell(row['mbps_at_60fps'], 8, 2)}{cell(row['fps'], 6, 1)}{cell(row['psnr_mean'], 10, 2)}"
                     f"{cell(row['psnr_min'], 7, 2)}{cell(row['psnr_source_mean'], 8, 2)}"
                     f"{cell(row['encode_ms'], 8, 2)}{cell(row['compose_ms'], 8, 2)}"
                     f"{cell(_sum(row.get('encode_wall_ms'), row.get('compose_wall_ms')), 6, 1)}"
                     f"{cell(row['viewer_decode_ms'], 8, 2)}{cell(row['latency_intervals_p50'], 8, 2)} "
                     f"({cell(row['latency_p50_ms'], 5, 0)} ms){row['keyframes']:>5}{row['frames_lost']:>5}")
    reference = ("render-once of each sampled frame's camera" if not run["synthetic"]
                 else "the coordinator's composite of the same frame (GET /api/frame.png)")
    lines.append(f"PSNR against {reference}; 'vs src': against the coordinator's composite of the tiles "
                 "(the encoder's source); enc/comp ms: the coordinator's CPU per frame (its stream thread), "
                 "wall: both on the wall clock; dec ms: this "
                 "viewer's CPU per frame; latency: input to decoded frame, in frame intervals (ms)")
    return "\n".join(lines)


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
    parser.add_argument("--json", type=Path, help="write the figures here")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    args.size = args.size or (SYNTHETIC_SIZE if args.synthetic else (1280, 720))
    args.nodes = args.nodes or (SYNTHETIC_NODES if args.synthetic else 3)
    if args.moving_s <= 1.0 or args.psnr_frames < 1:
        raise SystemExit("--moving-s must exceed 1 s and --psnr-frames be >= 1")
    result = measure(args)
    show_result(report(result), result, args.json, argv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
