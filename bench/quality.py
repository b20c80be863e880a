"""Interactive tile quality: bytes per frame against PSNR for JPEG qualities, with PNG (the lossless
still frame) and RAW for reference.

``python -m bench.quality [--scene S …] (--path P [--path P2 …] | --cameras N [--seed 0])
[--size 1280x720 | --sizes 640x360,1280x720,1920x1080] [--frames 12]
[--qualities 30,40,50,60,70,80,85,90,95 | none] [--msaa auto,…] [--still-samples auto,…] [--json OUT]``

Cameras: each ``--path`` is a camera path JSON (``bench/paths/*.json``, ``--frames`` evenly spaced
cameras of it) or a kind of :func:`bench.paths.make_path` (``orbit``, ``flythrough``, ``zoom``:
``--frames`` cameras made for that scene's bounds); one ``--path`` serves every scene, several pair
with the scenes in order. ``--cameras N`` instead: N random cameras around each scene
(:func:`bench.paths.random_cameras`, drawn from ``--seed`` and the scene's name: the same cameras
every run, others for each scene), for the JPEG rows and the picture rows alike. Without
``--scene``, the scenes of :mod:`bench.picture` (the diorama, truck, engine and four scans).
``--sizes``: every figure at each frame size (the cameras' aspect follows the size).

Each camera is rendered as one full frame with :class:`node.gl.renderer.TileRenderer` (one GL context
for the run), then encoded with :func:`tessera.wire.codec.encode` at each JPEG quality (4:2:0 chroma
below q90, 4:4:4 from q90, as the codec does), as PNG and as RAW, and decoded again with
:func:`tessera.wire.codec.decode`. Figures per scene and codec setting, against the rendered pixels:

- ``kb_mean``: mean encoded size per frame, KB (1000 bytes); ``mbit_s_30fps``: that at 30 frames/s.
- ``psnr_mean_db``, ``psnr_min_db``: mean and worst per-frame PSNR over the RGB channels, dB;
  ``null`` in the JSON ("lossless" in the table) when the decoded pixels equal the rendered ones.
- ``off8_fraction``: fraction of pixels whose error exceeds 8 levels (of 255) in any channel;
  ``max_error``: the largest error in levels over all frames.
- ``encode_ms``, ``decode_ms``: mean CPU time per frame of the calling thread (``time.thread_time``,
  so other processes on the machine do not count), ms.

Per scene, ``quality_for_35db`` and ``quality_for_40db`` are the smallest JPEG quality whose mean
PSNR reaches 35 and 40 dB (``null`` if none does): a reading aid for the interactive default.

Picture quality (issues 20, 37), with ``--msaa auto,filter,1,2,4,8`` and/or ``--still-samples
auto,1,2,4,8,16,32`` (``auto``: the service's adaptive still): at ``--picture-frames`` (default 2)
evenly spaced cameras of the scene's path, or every random camera, each ``--msaa`` setting's
interactive frame and each sample count's progressive still against the same camera rendered 4×4
supersampled, and their time per frame (``antialiasing`` and ``still`` per scene and size in the
JSON; figures and rows as :mod:`bench.picture` defines them, whose functions measure them).
``summary`` in the JSON (and the last table): per setting and frame size, over every scene and
camera, the mean PSNR and the worst (with the scene it came from), and for stills the most samples
and the longest still. Lambert against PBR shading is timed by ``python -m bench.shading``, which
runs the tree before PBR beside this one.
"""

from __future__ import annotations

import argparse
import io
import json
import platform
import sys
import time
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import moderngl
import numpy as np
from PIL import Image, JpegImagePlugin

from bench.culling import read_path
from bench.images import psnr
from bench.paths import KINDS, make_path, random_cameras, surface_focus
from bench.picture import (
    DEFAULT_SCENES,
    antialiasing_table,
    measure_antialiasing,
    measure_still,
    parse_counts,
    parse_still_counts,
    setting_name,
    still_table,
)
from node.gl.context import create_gl_context, renderer_string
from node.gl.renderer import TileRenderer
from node.scene.data import SceneData
from node.scene.loading import load_scene
from node.settings import parse_size
from tessera.geometry import Camera
from tessera.wire.codec import Codec, decode, encode

DEFAULT_QUALITIES = (30, 40, 50, 60, 70, 80, 85, 90, 95)
DEFAULT_FRAMES = 12
PSNR_MARKS_DB = (35, 40)
OFF_LEVELS = 8
FRAMES_PER_S = 30
CHROMA = {0: "4:4:4", 1: "4:2:2", 2: "4:2:0"}


def parse_qualities(text: str) -> list[int]:
    """'30,50,90' → [30, 50, 90], sorted, each 1…100; 'none' → [] (no JPEG rows)."""
    if text.strip().lower() == "none":
        return []
    qualities = sorted({int(part) for part in text.split(",") if part.strip()})
    if not qualities or not all(1 <= q <= 100 for q in qualities):
        raise argparse.ArgumentTypeError(f"JPEG qualities are integers 1..100, got {text!r}")
    return qualities


def compare(decoded: np.ndarray, reference: np.ndarray) -> tuple[float, float, int]:
    """PSNR in dB (``math.inf`` when equal), fraction of pixels off by more than :data:`OFF_LEVELS`
    in any channel, and the largest error in levels, of two (h, w, 3) uint8 images."""
    pixel_error = np.abs(decoded.astype(np.int16) - reference.astype(np.int16)).max(axis=2)
    return psnr(decoded, reference), float(np.mean(pixel_error > OFF_LEVELS)), int(pixel_error.max())


def jpeg_chroma(data: bytes) -> str:
    """The chroma subsampling of JPEG ``data`` as read from its header, e.g. '4:2:0'."""
    with Image.open(io.BytesIO(data)) as image:
        return CHROMA.get(JpegImagePlugin.get_sampling(image), "other")


def cpu_ms(call: Callable[..., Any], *args: Any) -> tuple[Any, float]:
    """``call(*args)``'s result and the CPU time of this thread it took, ms."""
    started = time.thread_time()
    result = call(*args)
    return result, (time.thread_time() - started) * 1e3


def warm_up_codecs() -> None:
    """Encode and decode a tiny image with every codec once, so Pillow's one-time plugin set-up is
    not timed as part of the first frame."""
    pixels = np.zeros((8, 8, 3), np.uint8)
    for codec in Codec:
        decode(encode(pixels, codec), codec, 8, 8)


def camera_seed(scene_spec: str, seed: int) -> int:
    """The random cameras' seed for a scene: ``seed`` and the scene's name (stable across runs and
    scene orders)."""
    return seed * 1_000_003 + zlib.crc32(scene_spec.encode())


def scene_cameras(path_spec: str, scene: SceneData, frames: int) -> list[Camera]:
    """``frames`` cameras: evenly spaced ones of a path JSON file, or a :data:`bench.paths.KINDS`
    path made for ``scene``'s bounds (zoom focused on the vertex nearest the default eye)."""
    if path_spec not in KINDS:
        return read_path(Path(path_spec), frames)[1]
    positions = np.concatenate([batch.positions for batch in scene.batches]).astype(np.float64)
    path = make_path(path_spec, scene.bounds, max(frames, 2), focus=surface_focus(positions, scene.bounds))
    return [Camera.from_json(camera) for camera in path["frames"]]


def settings(qualities: list[int]) -> list[tuple[str, Codec, int]]:
    """(name, codec, JPEG quality) for each JPEG quality, then PNG and RAW."""
    return [(f"jpeg q{q}", Codec.JPEG, q) for q in qualities] + [("png", Codec.PNG, 0), ("raw", Codec.RAW, 0)]


def measure_scene(ctx: moderngl.Context, scene_spec: str, scene: SceneData, load_s: float, cameras: list[Camera],
                  size: tuple[int, int], qualities: list[int]) -> dict[str, Any]:
    """Render ``cameras`` of one scene and measure every codec setting on each frame."""
    renderer = TileRenderer(ctx, scene)
    width, height = size
    samples: dict[str, dict[str, list[float]]] = {
        name: {"bytes": [], "psnr": [], "off8": [], "max_error": [], "encode_ms": [], "decode_ms": []}
        for name, _, _ in settings(qualities)}
    chroma: dict[str, str] = {}
    render_ms = []
    for camera in cameras:
        frame = renderer.render_frame(camera, size)
        render_ms.append(frame.render_ms + frame.readback_ms)
        for name, codec, quality in settings(qualities):
            data, encode_ms = cpu_ms(encode, frame.pixels, codec, quality)
            decoded, decode_ms = cpu_ms(decode, data, codec, width, height)
            psnr_db, off8, max_error = compare(decoded, frame.pixels)
            if codec is Codec.JPEG:
                chroma[name] = jpeg_chroma(data)
            for key, value in (("bytes", len(data)), ("psnr", psnr_db), ("off8", off8), ("max_error", max_error),
                               ("encode_ms", encode_ms), ("decode_ms", decode_ms)):
                samples[name][key].append(value)
    renderer.release()
    rows = []
    for name, codec, quality in settings(qualities):
        sample = samples[name]
        psnrs = np.asarray(sample["psnr"])
        lossless = bool(np.all(np.isinf(psnrs)))
        kb_mean = float(np.mean(sample["bytes"])) / 1e3
        rows.append({
            "setting": name, "codec": codec.name.lower(), "quality": quality if codec is Codec.JPEG else None,
            "chroma": chroma.get(name), "kb_mean": round(kb_mean, 2),
            "mbit_s_30fps": round(kb_mean * 8e3 * FRAMES_PER_S / 1e6, 2),
            "psnr_mean_db": None if lossless else round(float(np.mean(psnrs)), 3),
            "psnr_min_db": None if lossless else round(float(np.min(psnrs)), 3),
            "lossless": lossless, "off8_fraction": round(float(np.mean(sample["off8"])), 6),
            "max_error": int(max(sample["max_error"])),
            "encode_ms": round(float(np.mean(sample["encode_ms"])), 3),
            "decode_ms": round(float(np.mean(sample["decode_ms"])), 3),
        })
    report: dict[str, Any] = {
        "scene": scene_spec, "size": list(size), "frames": len(cameras), "triangles": scene.triangle_count,
        "load_s": round(load_s, 2), "render_ms_mean": round(float(np.mean(render_ms)), 2), "rows": rows,
    }
    for mark in PSNR_MARKS_DB:
        report[f"quality_for_{mark}db"] = next(
            (row["quality"] for row in rows
             if row["codec"] == "jpeg" and row["psnr_mean_db"] is not None and row["psnr_mean_db"] >= mark), None)
    return report


def print_scene(report: dict[str, Any], size: tuple[int, int]) -> None:
    print(f"\n{report['scene']}: {report['cameras']}, {report['frames']} frames at {size[0]}x{size[1]}, "
          f"{report['triangles']:,} triangles, render+readback {report['render_ms_mean']:.0f} ms/frame")
    print(f"{'setting':<10}{'chroma':>7}{'KB/frame':>10}{'Mbit/s@30':>11}{'PSNR mean':>11}{'PSNR min':>10}"
          f"{'>8 lvl':>9}{'max err':>8}{'enc ms':>8}{'dec ms':>8}")
    for row in report["rows"]:
        mean = "lossless" if row["lossless"] else f"{row['psnr_mean_db']:.2f}"
        worst = "lossless" if row["lossless"] else f"{row['psnr_min_db']:.2f}"
        print(f"{row['setting']:<10}{row['chroma'] or '-':>7}{row['kb_mean']:>10.1f}{row['mbit_s_30fps']:>11.1f}"
              f"{mean:>11}{worst:>10}{row['off8_fraction']:>9.2%}{row['max_error']:>8}"
              f"{row['encode_ms']:>8.1f}{row['decode_ms']:>8.1f}")
    marks = [f">= {mark} dB: " + (f"q{report[f'quality_for_{mark}db']}" if report[f"quality_for_{mark}db"] is not None
                                  else "none measured") for mark in PSNR_MARKS_DB]
    print("smallest JPEG quality with mean PSNR " + "; ".join(marks))


def summary(scenes: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per picture setting (an ``--msaa`` row or a still's count) and frame size, over every scene
    and camera: ``psnr_mean_db`` (the mean of the scenes' means), ``psnr_worst_db`` and the scene
    it came from; for stills also ``samples_max`` and ``still_ms_max``."""
    groups: dict[tuple[str, str], list[tuple[dict[str, Any], str]]] = {}
    for scene in scenes:
        size = "x".join(map(str, scene["size"]))
        for row in scene.get("antialiasing", {}).get("rows", []):
            groups.setdefault((f"interactive {setting_name(row)}", size), []).append((row, scene["scene"]))
        for row in scene.get("still", {}).get("rows", []):
            name = "auto" if row.get("adaptive") else str(row["samples"])
            groups.setdefault((f"still {name}", size), []).append((row, scene["scene"]))
    out = []
    for (setting, size), rows in groups.items():
        worst, worst_scene = min(((row["psnr_min_db"], scene) for row, scene in rows), key=lambda pair: pair[0])
        entry: dict[str, Any] = {"setting": setting, "size": size, "scenes": len(rows),
                                 "psnr_mean_db": round(float(np.mean([row["psnr_mean_db"] for row, _ in rows])), 2),
                                 "psnr_worst_db": worst, "worst_scene": worst_scene}
        if setting.startswith("still"):
            entry["samples_max"] = max(row["samples_max"] for row, _ in rows)
            entry["still_ms_max"] = round(max(row["still_ms_max"] for row, _ in rows), 1)
        else:
            entry["frame_ms_max"] = round(max(row["frame_ms"] for row, _ in rows), 1)
        out.append(entry)
    return out


def summary_table(entries: list[dict[str, Any]]) -> str:
    lines = [f"{'worst case over scenes and cameras':<36} {'size':>10} {'mean dB':>8} {'worst dB':>9} "
             f"{'most N':>7} {'ms max':>8}  worst scene"]
    for entry in entries:
        most = entry.get("samples_max", "")
        ms = entry.get("still_ms_max", entry.get("frame_ms_max"))
        lines.append(f"{entry['setting']:<36} {entry['size']:>10} {entry['psnr_mean_db']:>8.2f} "
                     f"{entry['psnr_worst_db']:>9.2f} {most:>7} {ms:>8.1f}  {Path(entry['worst_scene']).name}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    args_list = sys.argv[1:] if argv is None else list(argv)
    parser = argparse.ArgumentParser(prog="python -m bench.quality", description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", action="append",
                        help="scene file or builtin:NAME (repeatable; default: bench.picture's scenes)")
    parser.add_argument("--path", action="append",
                        help=f"camera path JSON or one of {', '.join(KINDS)} (repeatable: one per scene, in order)")
    parser.add_argument("--cameras", type=int, help="instead of --path: this many random cameras around each scene")
    parser.add_argument("--seed", type=int, default=0, help="the random cameras' seed (default 0)")
    parser.add_argument("--size", type=parse_size, default=(1280, 720), help="WxH (default 1280x720)")
    parser.add_argument("--sizes", type=lambda text: [parse_size(part) for part in text.split(",") if part.strip()],
                        help="WxH,WxH,…: every figure at each of these sizes (instead of --size)")
    parser.add_argument("--frames", type=int, default=DEFAULT_FRAMES,
                        help=f"evenly spaced cameras per scene of a --path (default {DEFAULT_FRAMES})")
    parser.add_argument("--qualities", type=parse_qualities, default=list(DEFAULT_QUALITIES),
                        help="JPEG qualities, comma-separated (default " + ",".join(map(str, DEFAULT_QUALITIES))
                             + "), or none for no JPEG rows")
    parser.add_argument("--msaa", type=parse_counts, default=[],
                        help="also the interactive frame's PSNR against the 4x4 supersampled one and its time at "
                             "these --msaa settings (of auto, filter, 1, 2, 4, 8)")
    parser.add_argument("--still-samples", type=parse_still_counts, default=[],
                        help="also the progressive still's PSNR against it at these sample counts (auto: the "
                             "adaptive still)")
    parser.add_argument("--picture-frames", type=int, default=2,
                        help="cameras of each path those are measured at (default 2; every random camera)")
    parser.add_argument("--json", type=Path, help="write the report here")
    args = parser.parse_args(args_list)
    scenes_given = args.scene or list(DEFAULT_SCENES)
    if args.cameras is None and not args.path:
        parser.error("give --path (a camera path per scene, or one for all) or --cameras N")
    if args.cameras is not None and (args.path or args.cameras < 1):
        parser.error("--cameras N (N >= 1) replaces --path")
    if args.path and len(args.path) not in (1, len(scenes_given)):
        parser.error(f"give one --path for all scenes or one per scene; got {len(args.path)} for "
                     f"{len(scenes_given)} scenes")
    if args.frames < 1 or args.picture_frames < 1:
        parser.error("--frames and --picture-frames must be at least 1")
    paths = (args.path * len(scenes_given) if len(args.path) == 1 else args.path) if args.path else []
    sizes = args.sizes or [args.size]
    warm_up_codecs()
    ctx = create_gl_context()
    renderer_name = renderer_string(ctx)
    print(f"{renderer_name}; python {platform.python_version()}")
    scenes = []
    for index, scene_spec in enumerate(scenes_given):
        started = time.perf_counter()
        scene = load_scene(scene_spec)
        load_s = time.perf_counter() - started
        for size in sizes:
            if args.cameras is not None:
                cameras = random_cameras(scene.bounds, args.cameras, camera_seed(scene_spec, args.seed),
                                         aspect=size[0] / size[1])
                described, picture_cameras = f"{args.cameras} random cameras (seed {args.seed})", cameras
            else:
                cameras = scene_cameras(paths[index], scene, args.frames)
                described = f"path {paths[index]}"
                picture_cameras = scene_cameras(paths[index], scene, args.picture_frames) \
                    if args.msaa or args.still_samples else []
            report = measure_scene(ctx, scene_spec, scene, load_s, cameras, size, args.qualities) \
                if args.qualities else {"scene": scene_spec, "size": list(size), "frames": len(cameras), "rows": []}
            report["cameras"] = described
            scenes.append(report)
            if args.qualities:
                print_scene(report, size)
            if args.msaa:
                report["antialiasing"] = measure_antialiasing(ctx, scene_spec, size, len(picture_cameras), args.msaa,
                                                              cameras=picture_cameras, scene=scene)
                print(antialiasing_table([report["antialiasing"]]), flush=True)
            if args.still_samples:
                report["still"] = measure_still(ctx, scene_spec, size, len(picture_cameras), args.still_samples,
                                                cameras=picture_cameras, scene=scene)
                print(still_table([report["still"]]), flush=True)
    ctx.release()
    worst = summary(scenes)
    if worst:
        print("\n" + summary_table(worst))
    if args.json is not None:
        meta = {"scenes": scenes_given, "paths": paths, "cameras": args.cameras, "seed": args.seed,
                "size": list(sizes[0]), "sizes": [list(size) for size in sizes], "frames": args.frames,
                "qualities": args.qualities, "renderer": renderer_name, "python": platform.python_version(),
                "argv": args_list}
        args.json.write_text(json.dumps({"meta": meta, "scenes": scenes, "summary": worst}, indent=2,
                                        allow_nan=False) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
