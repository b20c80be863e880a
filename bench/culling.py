"""Sort-first without redundant geometry: octree pre-split + per-tile culling on a camera path
(seeds 002 §3.4, 001 §6).

``python -m bench.culling --scene PATH --path PATH.json --tiles T --size WxH [--json OUT]
[--face-limit N] [--culling hybrid|cpu|gpu] [--repeats 2] [--frames N] [--time-per-frame S
[--start-time T]]``

Renders each frame of the path (or ``--frames`` evenly spaced ones) in one GL context with
:class:`node.gl.renderer.TileRenderer`: once whole without culling (the reference, as
``--render-once`` draws it), once whole with culling, and as T tiles (the equal strip partition)
with culling off, CPU, GPU and hybrid, and CPU culling drawn by one draw call per index run
instead of one multi-draw-indirect per batch (``cpu-ranges``, to compare the two draw APIs).
Each tile is rendered ``--repeats`` times in a row and its render time (cull + draw + glFinish)
is the fastest; the hybrid switch counts each repeat as a frame. Tile slots keep their index
from frame to frame, as under push balancing.

An animated scene (issue 11) plays along the path with ``--time-per-frame S``: path frame i is
drawn in the scene's state at ``--start-time`` + i·S seconds (its animations sampled there), so
moved objects are culled where they are (:mod:`node.culling.objects`) in every figure; without it
every frame shows the base pose.

Figures: ``redundancy`` = triangles submitted over all tiles / triangles submitted for the whole
frame, both with culling; ``psnr_min`` = worst PSNR of the stitched tiles (culling on) against the
unculled whole frame, 100 standing for identical; ``cull_speedup`` = summed tile render time
without culling / with ``--culling``.

llvmpipe rasterizes on ``LP_NUM_THREADS`` threads (unset: one per core) but transforms and sets up
triangles on the calling thread, so the figure depends on it: culling removes vertex work from
every tile, and what is left of a culled tile is mostly rasterization. The thread count is printed
and written to the report.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench.images import psnr, reported_psnr
from node.culling.switch import CullMode, resolve_culling
from node.culling.tiles import TileCuller
from node.gl.context import create_gl_context, renderer_string
from node.gl.renderer import TileRenderer
from node.scene.loading import load_scene
from node.scene.octree import DEFAULT_FACE_LIMIT
from node.settings import parse_size
from tessera.balancers.partition import equal_strip_partition
from tessera.geometry import Camera

GOALS = {"redundancy": ("<=", 1.10), "psnr_min": (">=", 50.0), "cull_speedup": (">=", 5.0)}
MODES = ("off", "cpu", "gpu", "hybrid", "cpu-ranges")


def read_path(path: Path, frames: int | None) -> tuple[list[int], list[Camera]]:
    """The path's frame indices used and their cameras (``frames`` evenly spaced ones when given)."""
    data = json.loads(path.read_text())
    cameras = [Camera.from_json(c) for c in data["frames"]]
    indices = list(range(len(cameras)))
    if frames is not None and frames < len(cameras):
        indices = np.linspace(0, len(cameras) - 1, frames).round().astype(int).tolist()
    return indices, [cameras[i] for i in indices]


def run(scene_spec: str, cameras: list[Camera], tiles: int, size: tuple[int, int], face_limit: int,
        culling: str, repeats: int, times: list[float] | None = None) -> dict[str, Any]:
    """The report for ``cameras``; ``times``: each frame's scene time in s (None: the base pose)."""
    started = time.perf_counter()
    scene = load_scene(scene_spec, face_limit=face_limit)
    load_s = time.perf_counter() - started
    states = [None] * len(cameras) if times is None else [scene.state_at(t) for t in times]
    ctx = create_gl_context()
    asked, culling = culling, resolve_culling(CullMode(culling), ctx.info["GL_RENDERER"]).value
    renderer = TileRenderer(ctx, scene, culling=CullMode.OFF)
    ranges = TileRenderer(ctx, scene, culling=CullMode.CPU)
    ranges.multi_draw = False
    cullers = {mode: TileCuller(ctx, scene.chunks, CullMode(mode)) for mode in ("off", "cpu", "gpu", "hybrid")}
    rects = equal_strip_partition(tiles, size)
    chunk_total = scene.chunks.chunk_count
    samples: dict[str, dict[str, list[Any]]] = {m: {"ms": [], "cull_ms": [], "tris": [], "chunks": [], "path": []}
                                                for m in MODES}
    whole: dict[str, list[float]] = {"off_ms": [], "on_ms": [], "on_tris": []}
    psnrs: dict[str, list[float]] = {m: [] for m in MODES}
    for camera, state in zip(cameras, states, strict=True):
        renderer.culler = cullers["off"]
        reference = renderer.render_frame(camera, size, state)
        renderer.culler = cullers[culling]
        whole_on = renderer.render_frame(camera, size, state)
        whole["off_ms"].append(reference.render_ms)
        whole["on_ms"].append(whole_on.render_ms)
        whole["on_tris"].append(whole_on.triangles)
        for mode in MODES:
            drawer = ranges if mode == "cpu-ranges" else renderer
            if mode != "cpu-ranges":
                renderer.culler = cullers[mode]
            stitched = np.zeros_like(reference.pixels)
            for slot, rect in enumerate(rects):
                best = min((drawer.render_tile(camera, size, rect, slot, state) for _ in range(repeats)),
                           key=lambda tile: tile.render_ms)
                stitched[rect.y:rect.y1, rect.x:rect.x1] = best.pixels
                record = samples[mode]
                record["ms"].append(best.render_ms)
                record["cull_ms"].append(best.cull_ms)
                record["tris"].append(best.triangles)
                record["chunks"].append(best.chunks_drawn)
                record["path"].append(best.cull_path)
                assert best.chunks_drawn + best.chunks_culled == chunk_total
            psnrs[mode].append(psnr(stitched, reference.pixels))
    frames = len(cameras)
    modes = {}
    for mode, record in samples.items():
        ms = np.asarray(record["ms"])
        paths = {p: record["path"].count(p) for p in sorted(set(record["path"]))}
        modes[mode] = {
            "tile_ms_sum": round(float(ms.sum()), 2), "tile_ms_mean": round(float(ms.mean()), 3),
            "tile_ms_p90": round(float(np.percentile(ms, 90)), 3),
            "cull_ms_mean": round(float(np.mean(record["cull_ms"])), 4),
            "triangles_per_frame": round(float(np.sum(record["tris"])) / frames),
            "chunks_drawn_per_tile": round(float(np.mean(record["chunks"])), 1),
            "paths": paths, "psnr_min": reported_psnr(min(psnrs[mode])),
            "identical_frames": sum(p == math.inf for p in psnrs[mode]),
        }
    for drawer in (renderer, ranges):
        drawer.release()
    for culler in cullers.values():
        culler.release()
    renderer_name = renderer_string(ctx)
    ctx.release()
    tile_tris = float(np.sum(samples[culling]["tris"]))
    return {
        "scene": scene_spec, "size": list(size), "tiles": tiles, "frames": frames, "repeats": repeats,
        "face_limit": face_limit, "chunks": chunk_total, "triangles": scene.triangle_count,
        "scene_times": None if times is None else [round(t, 6) for t in times],
        "load_s": round(load_s, 2), "renderer": renderer_name, "culling": culling, "culling_asked": asked,
        "lp_num_threads": os.environ.get("LP_NUM_THREADS", "unset"),
        "redundancy": round(tile_tris / float(np.sum(whole["on_tris"])), 4),
        "psnr_min": modes[culling]["psnr_min"],
        "cull_speedup": round(modes["off"]["tile_ms_sum"] / modes[culling]["tile_ms_sum"], 3),
        "cull_speedup_by_mode": {mode: round(modes["off"]["tile_ms_sum"] / modes[mode]["tile_ms_sum"], 3)
                                 for mode in MODES if mode != "off"},
        "whole_frame": {"off_ms_mean": round(float(np.mean(whole["off_ms"])), 2),
                        "culled_ms_mean": round(float(np.mean(whole["on_ms"])), 2),
                        "culled_triangles_per_frame": round(float(np.mean(whole["on_tris"])))},
        "modes": modes,
    }


def goal_met(report: dict[str, Any], name: str) -> bool:
    op, bound = GOALS[name]
    return report[name] <= bound if op == "<=" else report[name] >= bound


def print_report(report: dict[str, Any]) -> None:
    times = report["scene_times"]
    if times is not None:
        print(f"animation played along the path: scene time {times[0]:g} .. {times[-1]:g} s")
    print(f"{report['scene']}: {report['triangles']} triangles in {report['chunks']} chunks "
          f"(face limit {report['face_limit']}), {report['frames']} frames x {report['tiles']} tiles at "
          f"{report['size'][0]}x{report['size'][1]}, min of {report['repeats']} repeats; {report['renderer']}; "
          f"LP_NUM_THREADS {report['lp_num_threads']}")
    print(f"{'tiles drawn with':<16}{'sum ms':>10}{'ms/tile':>9}{'p90':>8}{'cull ms':>9}{'tris/frame':>12}"
          f"{'chunks/tile':>12}{'psnr min':>9}  paths")
    for mode, row in report["modes"].items():
        paths = " ".join(f"{k}:{v}" for k, v in row["paths"].items())
        print(f"{mode:<16}{row['tile_ms_sum']:>10.1f}{row['tile_ms_mean']:>9.2f}{row['tile_ms_p90']:>8.2f}"
              f"{row['cull_ms_mean']:>9.3f}{row['triangles_per_frame']:>12}{row['chunks_drawn_per_tile']:>12.1f}"
              f"{row['psnr_min']:>9.1f}  {paths}")
    whole = report["whole_frame"]
    print(f"whole frame: {whole['off_ms_mean']:.1f} ms unculled, {whole['culled_ms_mean']:.1f} ms culled, "
          f"{whole['culled_triangles_per_frame']} triangles submitted")
    print("cull_speedup by mode: " + ", ".join(f"{k} {v:.2f}" for k, v in report["cull_speedup_by_mode"].items()))
    for name, (op, bound) in GOALS.items():
        print(f"{name:<14}{report[name]:>9.3f}   goal {op} {bound:<6} {'met' if goal_met(report, name) else 'MISSED'}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.culling", description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", required=True)
    parser.add_argument("--path", required=True, type=Path, help="camera path JSON (bench/paths/*.json)")
    parser.add_argument("--tiles", type=int, default=16)
    parser.add_argument("--size", type=parse_size, default=(1280, 720))
    parser.add_argument("--face-limit", type=int, default=DEFAULT_FACE_LIMIT)
    parser.add_argument("--culling", choices=("auto", "hybrid", "cpu", "gpu"), default="auto",
                        help="the culling mode the figures are for, as the node's --culling (default auto: "
                             "hybrid on a hardware GPU, cpu on llvmpipe); all modes are measured")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--frames", type=int, help="use this many evenly spaced frames of the path")
    parser.add_argument("--time-per-frame", type=float, metavar="S",
                        help="play the scene's animation along the path: frame i at --start-time + i*S s")
    parser.add_argument("--start-time", type=float, default=0.0, metavar="T", help="scene time of frame 0 (s)")
    parser.add_argument("--json", type=Path, help="write the report here")
    args = parser.parse_args(argv)
    indices, cameras = read_path(args.path, args.frames)
    times = None if args.time_per_frame is None else [args.start_time + i * args.time_per_frame for i in indices]
    report = run(args.scene, cameras, args.tiles, args.size, args.face_limit, args.culling, max(1, args.repeats),
                 times)
    report["path"] = str(args.path)
    print_report(report)
    if args.json is not None:
        args.json.write_text(json.dumps(report, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
