"""The H.264 stream's bytes against the tiles' at equal PSNR, offline (issue 37): orbit frames from
random cameras rendered in this process (the interactive frame, as :class:`bench.stream.References`
renders it), each coded as a tile viewer gets it — JPEG at the interactive quality, one tile a
frame, then permessage-deflate as the coordinator's WebSocket compresses a message (one
compressor a stream, its window kept) — and as the video stream codes it, with the coordinator's
own :class:`server.video_encoder.VideoEncoder` decoded with PyAV as the benchmark's viewer decodes
it. The video runs at each of ``--crfs`` and its bytes are interpolated (log-linear in PSNR; beyond the CRFs' range,
extrapolated) at the tiles' mean PSNR: the ratio of the two is what the video would cost on the wire at the tiles'
picture. No coordinator, no nodes, no timing of the cluster: the same frames for every variant.

``--loop``: each camera's frames also go through the stream's CRF loop
(:mod:`tessera.video.quality_control`) as the coordinator runs it — a new encoder (a keyframe) at each
CRF it moves to, every frame measured that the probe may measure (:data:`server.video_quality.SETTLE_FRAMES`
after a keyframe not), from :func:`server.video_encoder.default_crf` — and the figures of the last
half of the frames are what the loop holds: the video's PSNR less the tiles' and its bytes over
theirs on the wire, keyframes included.

``python -m bench.video_rd --scene S --sizes 640x360,1280x720 --cameras 4 --frames 24 --step-deg 30
--variants shipped,reopen:12,x264:ref=3 [--crfs 22,25,28,31] [--quality 60] [--loop] [--json OUT]``

``--step-deg``: the camera's turn between frames. ``bench.stream``'s orbit turns once in 2 s, so
a stream at F frames a second turns 180/F degrees a frame (30° at 6 fps, 10° at 18 fps).
Variants: ``shipped`` (the encoder as the coordinator opens it), ``reopen:K`` (a new encoder, and
so a keyframe, every K frames: what a CRF change costs), ``x264:OPTS`` (x264 options appended to
the shipped ones, ``:``-separated as x264 takes them).
"""

from __future__ import annotations

import argparse
import io
import math
import sys
import time
import zlib
from pathlib import Path
from typing import Any

import av
import numpy as np
from av.video.codeccontext import VideoCodecContext
from PIL import Image

from bench.paths import orbit_around, random_cameras
from bench.processes import show_result
from bench.stream import References, sizes_parser
from node.scene.loading import load_scene
from server.settings import DEFAULT_MAX_BITRATE
from server.video_encoder import VideoEncoder, default_crf
from server.video_quality import SETTLE_FRAMES, psnr_db
from server.video_stream import default_bitrate
from tessera.geometry import Rect
from tessera.scheduling.config import SchedulerConfig
from tessera.video.quality_control import CrfLoop, observe
from tessera.video.yuv_frame import compose_yuv420, decoded_planes, rgb_of_yuv420
from tessera.wire.codec import Codec, encode
from tessera.wire.video import VideoCodec

#: The stream's nominal frame rate (the coordinator's default).
FPS = SchedulerConfig().max_fps


def deflated_sizes(messages: list[bytes]) -> list[int]:
    """Bytes on the wire of each of ``messages`` sent in order on one WebSocket with
    permessage-deflate as websockets offers it (a 2¹² window, memLevel 5, the window kept)."""
    compressor = zlib.compressobj(wbits=-12, memLevel=5)
    return [len(compressor.compress(m) + compressor.flush(zlib.Z_SYNC_FLUSH)) - 4 for m in messages]


def tiles_frames(frames: np.ndarray, quality: int) -> tuple[list[int], list[float]]:
    """Bytes on the wire and PSNR (dB) of each of ``frames`` (N, h, w, 3) uint8 as a JPEG tile at
    ``quality``."""
    jpegs = [encode(frame, Codec.JPEG, quality) for frame in frames]
    decoded = [np.asarray(Image.open(io.BytesIO(j)).convert("RGB")) for j in jpegs]
    return deflated_sizes(jpegs), [psnr_db(d, f) for d, f in zip(decoded, frames, strict=True)]


def tiles_figures(frames: np.ndarray, quality: int) -> tuple[float, float]:
    """Mean bytes on the wire a frame and mean PSNR (dB) of ``frames`` (N, h, w, 3) uint8 as JPEG
    tiles at ``quality``."""
    sizes, dbs = tiles_frames(frames, quality)
    return float(np.mean(sizes)), float(np.mean(dbs))


def parse_variant(text: str) -> tuple[int, str]:
    """(frames between new encoders, 0: never; extra x264 options) of a ``--variants`` entry."""
    if text == "shipped":
        return 0, ""
    kind, _, value = text.partition(":")
    if kind == "reopen" and value.isdigit() and int(value) > 0:
        return int(value), ""
    if kind == "x264" and value:
        return 0, value
    raise argparse.ArgumentTypeError(f"variant {text!r}: shipped, reopen:K or x264:OPTS")


def coded_frame(encoder: VideoEncoder, decoder: VideoCodecContext, frame: np.ndarray) -> tuple[int, float, float]:
    """Bytes, PSNR (dB) of the decoded picture and encode CPU ms of ``frame`` (h, w, 3) uint8
    through ``encoder``, decoded by ``decoder`` as the benchmark's viewer decodes."""
    h, w = frame.shape[:2]
    planes = compose_yuv420((w, h), [(Rect(0, 0, w, h), Codec.RAW, 0, np.ascontiguousarray(frame).tobytes())])
    started = time.thread_time()
    units = encoder.encode(planes, False)
    cpu_ms = (time.thread_time() - started) * 1000.0
    pictures = [p for unit, _ in units for p in decoder.decode(av.Packet(unit))]
    db = float(np.mean([psnr_db(rgb_of_yuv420(decoded_planes(p), (w, h)), frame) for p in pictures]))
    return sum(len(unit) for unit, _ in units), db, cpu_ms


def h264_decoder() -> VideoCodecContext:
    """A decoder of the stream, as the benchmark's viewer opens one."""
    decoder = av.CodecContext.create("h264", "r")
    assert isinstance(decoder, VideoCodecContext)
    return decoder


def stream_bitrate(frames: np.ndarray) -> float:
    """The H.264 stream's bitrate cap (bit/s) for frames of the shape of ``frames``."""
    h, w = frames.shape[1:3]
    return default_bitrate(VideoCodec.H264, (w, h), FPS, DEFAULT_MAX_BITRATE)


def video_figures(frames: np.ndarray, crf: float, variant: str) -> tuple[float, float, float]:
    """Mean bytes a frame, mean PSNR (dB) of the decoded frames and mean encode CPU ms a frame of
    ``frames`` (N, h, w, 3) uint8 through the stream's H.264 encoder at ``crf`` as ``variant`` opens it."""
    reopen, extra = parse_variant(variant)
    h, w = frames.shape[1:3]
    decoder = h264_decoder()
    encoder: VideoEncoder | None = None
    coded = []
    for index, frame in enumerate(frames):
        if encoder is None or (reopen and index % reopen == 0):
            encoder = VideoEncoder(VideoCodec.H264, (w, h), stream_bitrate(frames), FPS, crf, extra_params=extra)
        coded.append(coded_frame(encoder, decoder, frame))
    sizes, dbs, cpu_ms = zip(*coded, strict=True)
    return float(np.mean(sizes)), float(np.mean(dbs)), float(np.mean(cpu_ms))


def loop_figures(frames: np.ndarray, quality: int) -> dict[str, float]:
    """``frames`` (N, h, w, 3) uint8 through the stream's CRF loop against JPEG tiles at
    ``quality``: over the last half of the frames, the video's mean PSNR less the tiles' (dB) and
    its bytes over theirs on the wire; the CRF at the end and the changes made."""
    h, w = frames.shape[1:3]
    tiles_sizes, tiles_dbs = tiles_frames(frames, quality)
    decoder = h264_decoder()
    loop, encoder, since_keyframe = CrfLoop(default_crf((w, h))), None, 0
    sizes, dbs = [], []
    for frame, tiles_db in zip(frames, tiles_dbs, strict=True):
        if encoder is None or encoder.crf != loop.crf:   # a new CRF opens a new encoder, as the stream does
            encoder, since_keyframe = VideoEncoder(VideoCodec.H264, (w, h), stream_bitrate(frames), FPS, loop.crf), 0
        size, db, _ = coded_frame(encoder, decoder, frame)
        sizes.append(size)
        dbs.append(db)
        if since_keyframe >= SETTLE_FRAMES:
            loop = observe(loop, db, tiles_db, loop.crf)
        since_keyframe += 1
    held = slice(len(frames) // 2, None)
    return {"db_diff": round(float(np.mean(dbs[held]) - np.mean(tiles_dbs[held])), 3),
            "ratio": round(float(np.sum(sizes[held]) / np.sum(tiles_sizes[held])), 4), "crf": loop.crf,
            "changes": loop.changes}


def bytes_at(target_db: float, points: list[tuple[float, float]]) -> float:
    """Bytes at ``target_db`` interpolated log-linearly in PSNR between ``points`` (PSNR dB, bytes;
    two or more), beyond them extrapolated along the nearest two."""
    points = sorted(points)
    index = min(max(int(np.searchsorted([p[0] for p in points], target_db)), 1), len(points) - 1)
    (db0, size0), (db1, size1) = points[index - 1], points[index]
    slope = (math.log(size1) - math.log(size0)) / (db1 - db0) if db1 != db0 else 0.0
    return math.exp(math.log(size0) + slope * (target_db - db0))


def measure_camera(frames: np.ndarray, args: argparse.Namespace) -> dict[str, Any]:
    """One camera's orbit: the tiles' figures and each variant's ratio to them."""
    tiles_bytes, tiles_db = tiles_figures(frames, args.quality)
    out: dict[str, Any] = {"tiles_bytes": round(tiles_bytes, 1), "tiles_psnr": round(tiles_db, 2), "variants": {}}
    for variant in args.variants:
        runs = [video_figures(frames, crf, variant) for crf in args.crfs]
        at = bytes_at(tiles_db, [(db, size) for size, db, _ in runs])
        out["variants"][variant] = {"ratio": round(at / tiles_bytes, 4), "encode_ms": round(float(np.mean(
            [ms for _, _, ms in runs])), 2), "points": [[crf, round(size, 1), round(db, 2)] for crf, (size, db, _)
                                                        in zip(args.crfs, runs, strict=True)]}
    if args.loop:
        out["loop"] = loop_figures(frames, args.quality)
    return out


def measure(args: argparse.Namespace) -> dict[str, Any]:
    """Every size's cameras: per camera the figures of :func:`measure_camera`, per variant the mean
    and worst ratio."""
    scene = load_scene(args.scene)
    result: dict[str, Any] = {"scene": args.scene, "sizes": {}}
    for w, h in args.sizes:
        references = References(scene, (w, h))
        try:
            cameras = []
            for camera in random_cameras(scene.bounds, args.cameras, seed=args.seed, aspect=w / h):
                path = orbit_around(camera, frames=max(1, round(360.0 / args.step_deg)))["frames"]
                frames = np.stack([references.image(path[i % len(path)]) for i in range(args.frames)])
                cameras.append(measure_camera(frames, args))
        finally:
            references.release()
        summary = {}
        for variant in args.variants:
            ratios = [c["variants"][variant]["ratio"] for c in cameras]
            summary[variant] = {"ratio_mean": round(float(np.mean(ratios)), 3), "ratio_worst": round(max(ratios), 3),
                                "encode_ms": round(float(np.mean([c["variants"][variant]["encode_ms"]
                                                                  for c in cameras])), 2)}
        if args.loop:
            diffs, ratios = [c["loop"]["db_diff"] for c in cameras], [c["loop"]["ratio"] for c in cameras]
            summary["loop"] = {"db_diff_mean": round(float(np.mean(diffs)), 2), "db_diff_worst": min(diffs),
                               "ratio_mean": round(float(np.mean(ratios)), 3), "ratio_worst": max(ratios)}
        result["sizes"][f"{w}x{h}"] = {"cameras": cameras, "summary": summary}
    return result


def report(result: dict[str, Any]) -> str:
    """The table: per size and variant, the ratio of video to tiles' bytes on the wire at the tiles'
    PSNR (mean / worst over the cameras) and the encode CPU ms a frame."""
    lines = [f"{result['scene']}: H.264 bytes / tiles' bytes on the wire at the tiles' PSNR",
             f"{'size':<10}{'variant':<28}{'mean':>7}{'worst':>7}{'enc ms':>8}"]
    for size, figures in result["sizes"].items():
        for variant, row in figures["summary"].items():
            if variant == "loop":
                lines.append(f"{size:<10}{'CRF loop: ratio held':<28}{row['ratio_mean']:>7.3f}"
                             f"{row['ratio_worst']:>7.3f}   video - tiles {row['db_diff_mean']:+.2f} dB mean, "
                             f"{row['db_diff_worst']:+.2f} worst")
                continue
            lines.append(f"{size:<10}{variant:<28}{row['ratio_mean']:>7.3f}{row['ratio_worst']:>7.3f}"
                         f"{row['encode_ms']:>8.2f}")
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m bench.video_rd", description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="builtin:cluster")
    parser.add_argument("--sizes", type=sizes_parser, default=[(640, 360)], help="WxH,WxH,... (default 640x360)")
    parser.add_argument("--cameras", type=int, default=4, help="random cameras per size (default 4)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--frames", type=int, default=24, help="frames of each camera's orbit (default 24)")
    parser.add_argument("--step-deg", type=float, default=30.0, help="the camera's turn between frames (default 30)")
    parser.add_argument("--variants", default="shipped,reopen:12", help="comma-separated: shipped, reopen:K, x264:OPTS")
    parser.add_argument("--crfs", default="22,25,28,31", help="CRFs the video runs at (default 22,25,28,31)")
    parser.add_argument("--quality", type=int, default=SchedulerConfig().interactive_quality,
                        help="the tiles' JPEG quality (default the interactive quality)")
    parser.add_argument("--loop", action="store_true",
                        help="run each camera's frames through the stream's CRF loop too")
    parser.add_argument("--json", type=Path, help="write the figures here")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        args.variants = [v for v in args.variants.split(",") if v]
        for variant in args.variants:
            parse_variant(variant)
        args.crfs = sorted(float(c) for c in args.crfs.split(","))
    except (argparse.ArgumentTypeError, ValueError) as error:
        raise SystemExit(f"bench.video_rd: {error}") from error
    if args.cameras < 1 or args.frames < 2 or len(args.crfs) < 2 or not args.variants or args.step_deg <= 0:
        raise SystemExit("--cameras >= 1, --frames >= 2, two CRFs or more, a variant and --step-deg > 0 are needed")
    result = measure(args)
    show_result(report(result), result, args.json, argv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
