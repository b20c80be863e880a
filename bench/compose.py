"""Depth compositing benchmark: sort-first, the hybrid of seed 000 §4.4 and sort-last on a camera
path, serial replay (every tile or node layer rendered for real, one at a time, in one GL context).

``python -m bench.compose --scene S --path P --tiles N --size WxH --modes sort-first,hybrid,sort-last
[--depth-strip PX] [--strips 0,8,32] [--nodes 4] [--speeds s1,…] [--frames F] [--json OUT]``

Per frame of the path (or ``--frames`` evenly spaced ones, as ``bench.culling``) the whole frame is
rendered once: the reference, as ``--render-once --msaa 1`` draws it (depth layers are drawn at
one sample and not resolved by the anti-aliasing filter, so every mode draws so here), whose culled
triangles are the triangles in view. Then every mode:

- ``sort-first``: the ``--tiles`` tiles of the equal strip partition, each culled and drawn as a
  node draws it today, stitched.
- ``hybrid`` (and ``hybrid:PX`` for each width of ``--strips``): the same tiles, each drawing the
  chunks it owns and the shared ones touching it into tile + strip
  (:func:`node.gl.depth_layers.hybrid_plan`); colour and depth read back; the tile's core (what no
  other tile reaches) sent as colour alone and the strips with depth, active-pixel encoded
  (:func:`tessera.wire.active_pixels.encode_active`); decoded and merged.
- ``sort-last``: ``--nodes`` shares of the chunks (:func:`tessera.decomposition.data_partition.split_chunks`,
  sized by the calibration weights of ``--speeds``, slowdowns as in ``bench.balance``), each drawn
  over the whole frame and read back over the rect it projects to; encoded, decoded, merged.

Figures per mode (means per frame unless named otherwise): ``redundancy`` = triangles drawn by all
tiles or nodes / triangles in view; ``psnr_min`` (worst frame) against the reference, 100 for
identical; ``bytes_per_frame`` sent to the compositor, colour + depth (sort-first: raw RGB of the
tiles; hybrid: raw RGB of the cores and the strips' active-pixel encoding; sort-last: the
active-pixel encoding), of which ``depth_bytes`` carry depth and coverage (runs), and
``deflate_bytes`` the same payloads after zlib level 1 (what a lossless transport could send);
``compose_ms`` = merge CPU per frame on one core (depth modes: decoding every layer and merging;
sort-first: pasting the tiles); ``encode_ms`` the layers' encoding, summed;
``render_ms`` the layers' chunk choice (``plan_ms``, included), draw and read-back, summed;
``node_ms_max`` the slowest layer (in sort-last × its node's slowdown); ``readback_px`` pixels read
back; ``node_triangle_fraction`` = the most triangles one node loads / the scene's (1 where every
node holds the scene). Times are the calling thread's CPU time with llvmpipe rasterizing on it
(``LP_NUM_THREADS`` 0, set before the GL context), so other work on the machine does not blur them.
"""

from __future__ import annotations

import argparse
import json
import os
import struct
import time
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from bench.balance import parse_size, parse_speeds
from bench.culling import read_path
from bench.images import psnr, reported_psnr
from node.scene.octree import DEFAULT_FACE_LIMIT
from tessera.balancers.hetero import calibration_weights
from tessera.balancers.partition import equal_strip_partition
from tessera.compositing.depth_merge import merge_by_depth
from tessera.compositing.layers import DepthLayer, background_pixel, split_layer
from tessera.decomposition.chunk_ownership import DEFAULT_DEPTH_STRIP
from tessera.decomposition.data_partition import split_chunks
from tessera.geometry import Camera, Rect
from tessera.wire.active_pixels import decode_active, encode_active

MODES = ("sort-first", "hybrid", "sort-last")
GOALS: dict[str, dict[str, tuple[str, float]]] = {
    "hybrid": {"redundancy": ("<=", 1.02), "psnr_min": (">=", 50.0)},
    "sort-last": {"node_triangle_fraction": ("<=", 0.30), "psnr_min": (">=", 50.0)},
    "sort-first": {"psnr_min": (">=", 50.0)},
}
T = TypeVar("T")


def cpu_ms(action: Callable[[], T]) -> tuple[T, float]:
    """``action()`` and the calling thread's CPU milliseconds it took."""
    started = time.thread_time()
    result = action()
    return result, (time.thread_time() - started) * 1e3


def active_pixels(data: bytes) -> int:
    """Active pixels in an :func:`encode_active` payload (from its length and run count)."""
    pairs = struct.unpack_from("<I", data, 4)[0]
    return (len(data) - 8 - 8 * pairs) // 7


@dataclass(frozen=True, eq=False)
class Payload:
    """What one layer sends: the active-pixel encoding of each piece that carries depth (``pieces``:
    (rect, bytes)), and for a hybrid tile its ``core`` rect's colour (``core_pixels``, raw RGB)."""

    slot: int
    pieces: list[tuple[Rect, bytes]]
    core: Rect | None = None
    core_pixels: np.ndarray | None = None

    @property
    def core_bytes(self) -> int:
        return 0 if self.core_pixels is None else self.core_pixels.nbytes

    @property
    def sent(self) -> int:
        return sum(len(data) for _, data in self.pieces) + self.core_bytes

    @property
    def color_bytes(self) -> int:
        return 3 * sum(active_pixels(data) for _, data in self.pieces) + self.core_bytes

    def deflated(self) -> int:
        core = 0 if self.core_pixels is None else len(zlib.compress(self.core_pixels.tobytes(), 1))
        return sum(len(zlib.compress(data, 1)) for _, data in self.pieces) + core


def encode_layer(layer: Any, slot: int, core: Rect | None) -> Payload:
    """A rendered layer as it travels: its ``core`` (None: none) as raw colour, the pieces around it
    active-pixel encoded with depth (:func:`tessera.compositing.layers.split_layer`)."""
    pieces, core_pixels = split_layer(DepthLayer(layer.rect, layer.pixels, layer.depth, slot), core)
    return Payload(slot, [(piece.rect, encode_active(piece.depth, piece.color)) for piece in pieces], core,
                   core_pixels)


def merge_payloads(payloads: Sequence[Payload], size: tuple[int, int], background: np.ndarray) -> np.ndarray:
    """The compositor's work on a frame's layers: decode each piece, merge by depth, paste the cores."""
    layers, cores = [], []
    for payload in payloads:
        for rect, data in payload.pieces:
            depth, color = decode_active(data)
            layers.append(DepthLayer(rect, color, depth, payload.slot))
        if payload.core is not None and payload.core_pixels is not None:
            cores.append((payload.core, payload.core_pixels))
    return merge_by_depth(layers, size, background, cores)


class Tally:
    """One mode's per-frame figures and its worst PSNR."""

    def __init__(self) -> None:
        self.rows: dict[str, list[float]] = {}
        self.psnr_min = float("inf")

    def add(self, frame: np.ndarray, reference: np.ndarray, **values: float) -> None:
        self.psnr_min = min(self.psnr_min, psnr(frame, reference))
        for key, value in values.items():
            self.rows.setdefault(key, []).append(value)

    def summary(self, in_view: Sequence[int], fraction: float) -> dict[str, Any]:
        means = {key: round(float(np.mean(values)), 3) for key, values in self.rows.items()}
        return {"redundancy": round(float(np.sum(self.rows["triangles"])) / float(np.sum(in_view)), 4),
                "psnr_min": reported_psnr(self.psnr_min), "node_triangle_fraction": round(fraction, 4), **means}


def sort_first_frame(renderer: Any, camera: Camera, size: tuple[int, int], rects: Sequence[Rect]) -> tuple[
        np.ndarray, dict[str, float]]:
    """Today's tiles, stitched: the frame and its figures."""
    tiles, times = [], []
    for slot, rect in enumerate(rects):
        tile, ms = cpu_ms(lambda rect=rect, slot=slot: renderer.render_tile(camera, size, rect, slot))
        tiles.append(tile)
        times.append(ms)
    width, height = size

    def paste() -> np.ndarray:
        frame = np.empty((height, width, 3), np.uint8)
        for tile in tiles:
            frame[tile.rect.y:tile.rect.y1, tile.rect.x:tile.rect.x1] = tile.pixels
        return frame

    frame, compose_ms = cpu_ms(paste)
    sent = 3 * width * height
    return frame, {"triangles": sum(t.triangles for t in tiles), "bytes_per_frame": sent, "depth_bytes": 0,
                   "deflate_bytes": sum(len(zlib.compress(t.pixels.tobytes(), 1)) for t in tiles),
                   "compose_ms": compose_ms, "encode_ms": 0.0, "render_ms": sum(times), "plan_ms": 0.0,
                   "node_ms_max": max(times), "readback_px": width * height}


def depth_frame(renderer: Any, camera: Camera, size: tuple[int, int], planners: Sequence[Callable[[], Any]],
                slowdowns: Sequence[float]) -> tuple[np.ndarray, dict[str, float]]:
    """One frame of a depth mode: each of ``planners`` makes a layer's plan (None: no layer), which is
    drawn, read back and encoded; then all are decoded and merged. ``slowdowns`` scale each layer's
    time for ``node_ms_max``."""
    payloads: list[Payload] = []
    figures = dict.fromkeys(("triangles", "render_ms", "plan_ms", "encode_ms", "node_ms_max", "readback_px"), 0.0)
    for planner, slowdown in zip(planners, slowdowns, strict=True):
        plan, plan_ms = cpu_ms(planner)
        figures["plan_ms"] += plan_ms
        if plan is None:
            continue
        layer, draw_ms = cpu_ms(lambda plan=plan: renderer.render_layer(camera, size, plan.rect, plan.chunk_ids))
        payload, encode_ms = cpu_ms(lambda layer=layer, plan=plan: encode_layer(layer, len(payloads),
                                                                                plan.exclusive))
        payloads.append(payload)
        figures["triangles"] += layer.triangles
        figures["render_ms"] += plan_ms + draw_ms
        figures["encode_ms"] += encode_ms
        figures["node_ms_max"] = max(figures["node_ms_max"], (plan_ms + draw_ms) * slowdown)
        figures["readback_px"] += layer.rect.area
    frame, compose_ms = cpu_ms(lambda: merge_payloads(payloads, size, background_pixel(renderer.background)))
    sent = sum(p.sent for p in payloads)
    figures.update(bytes_per_frame=sent, depth_bytes=sent - sum(p.color_bytes for p in payloads),
                   deflate_bytes=sum(p.deflated() for p in payloads), compose_ms=compose_ms, layers=len(payloads))
    return frame, figures


def run(args: argparse.Namespace, cameras: list[Camera]) -> dict[str, Any]:
    from node.culling.switch import CullMode
    from node.gl.context import create_gl_context, renderer_string
    from node.gl.depth_layers import PlanningScene, hybrid_plan, sort_last_plan
    from node.gl.renderer import TileRenderer
    from node.gl.shading import ShadingOptions
    from node.scene.loading import load_scene

    started = time.perf_counter()
    scene = load_scene(args.scene, face_limit=args.face_limit)
    load_s = time.perf_counter() - started
    ctx = create_gl_context()
    renderer = TileRenderer(ctx, scene, culling=CullMode.CPU, shading=ShadingOptions(msaa=1))
    planning = PlanningScene.of(scene, renderer.culler.bvh)
    size, rects = args.size, equal_strip_partition(args.tiles, args.size)
    slowdowns = args.speeds or [1.0] * args.nodes
    weights = calibration_weights(dict(enumerate(slowdowns)))
    share_of = split_chunks(scene.chunks.boxes, scene.chunks.face_counts, [weights[i] for i in range(args.nodes)])
    shares = [np.flatnonzero(share_of == node) for node in range(args.nodes)]
    share_triangles = [int(scene.chunks.face_counts[share].sum()) for share in shares]
    strips = {f"hybrid:{px}": px for px in args.strips}
    if "hybrid" in args.modes:
        strips = {"hybrid": args.depth_strip, **strips}
    names = [m for m in args.modes if m != "hybrid"] + list(strips)
    tallies = {name: Tally() for name in names}
    in_view, whole_ms = [], []
    renderer.render_frame(cameras[0], size)  # warm-up: shader compilation, first touch
    for number, camera in enumerate(cameras):
        whole, ms = cpu_ms(lambda camera=camera: renderer.render_frame(camera, size))
        in_view.append(whole.triangles)
        whole_ms.append(ms)
        reference = whole.pixels
        if "sort-first" in names:
            frame, figures = sort_first_frame(renderer, camera, size, rects)
            tallies["sort-first"].add(frame, reference, **figures)
        for name, strip in strips.items():
            planners = [lambda index=index, camera=camera, strip=strip: hybrid_plan(planning, camera, size, rects,
                                                                                  index, strip)
                        for index in range(len(rects))]
            frame, figures = depth_frame(renderer, camera, size, planners, [1.0] * len(rects))
            tallies[name].add(frame, reference, **figures)
        if "sort-last" in names:
            planners = [lambda share=share, camera=camera: sort_last_plan(planning, camera, size, share)
                        for share in shares]
            frame, figures = depth_frame(renderer, camera, size, planners, slowdowns)
            tallies["sort-last"].add(frame, reference, **figures)
        print(f"  frame {number + 1}/{len(cameras)}: whole {ms:.0f} ms, {whole.triangles} triangles in view",
              flush=True)
    fractions = {"sort-last": max(share_triangles) / scene.triangle_count}
    report = {
        "scene": args.scene, "path": str(args.path), "size": list(size), "tiles": args.tiles, "nodes": args.nodes,
        "speeds": slowdowns, "frames": len(cameras), "face_limit": args.face_limit, "chunks": scene.chunks.chunk_count,
        "triangles": scene.triangle_count, "load_s": round(load_s, 1), "renderer": renderer_string(ctx),
        "lp_num_threads": os.environ.get("LP_NUM_THREADS", "unset"), "depth_strip": args.depth_strip,
        "share_triangles": share_triangles, "whole_ms": round(float(np.mean(whole_ms)), 2),
        "in_view_triangles": round(float(np.mean(in_view))),
        "modes": {name: tally.summary(in_view, fractions.get(name, 1.0)) for name, tally in tallies.items()},
    }
    renderer.release()
    ctx.release()
    return report


COLUMNS = {"redundancy": ".4f", "psnr_min": ".1f", "bytes_per_frame": ",.0f", "depth_bytes": ",.0f",
           "deflate_bytes": ",.0f", "compose_ms": ".1f", "encode_ms": ".1f", "render_ms": ".0f", "plan_ms": ".1f",
           "node_ms_max": ".1f", "readback_px": ",.0f", "node_triangle_fraction": ".3f"}


def goal_lines(report: dict[str, Any]) -> list[str]:
    """One line per goal of the issue: each mode's, and PSNR only for the extra ``hybrid:PX`` rows."""
    lines = []
    for name, row in report["modes"].items():
        base = name.split(":")[0]
        for key, (op, bound) in GOALS[base].items():
            if name != base and key != "psnr_min":
                continue
            met = row[key] <= bound if op == "<=" else row[key] >= bound
            lines.append(f"{name:<12}{key:<24}{row[key]:>9.4f}  goal {op} {bound:<6} {'met' if met else 'MISSED'}")
    return lines


def print_report(report: dict[str, Any]) -> None:
    speeds = ",".join(f"{s:g}" for s in report["speeds"])
    print(f"{report['scene']}: {report['triangles']} triangles in {report['chunks']} chunks, {report['frames']} "
          f"frames at {report['size'][0]}x{report['size'][1]}, {report['tiles']} tiles, sort-last on "
          f"{report['nodes']} nodes (slowdowns {speeds}; shares {report['share_triangles']} triangles); "
          f"{report['renderer']}; LP_NUM_THREADS {report['lp_num_threads']}")
    print(f"whole frame: {report['whole_ms']:.0f} ms, {report['in_view_triangles']} triangles in view")
    width = max(len("mode"), *(len(name) for name in report["modes"]))
    widths = {key: max(len(key), 10) + 2 for key in COLUMNS}
    print(f"{'mode':<{width}}" + "".join(f"{key:>{widths[key]}}" for key in COLUMNS))
    for name, row in report["modes"].items():
        print(f"{name:<{width}}" + "".join(f"{row[key]:>{widths[key]}{spec}}" for key, spec in COLUMNS.items()))
    for line in goal_lines(report):
        print(line)


def parse_list(text: str) -> list[str]:
    return [item.strip() for item in text.split(",") if item.strip()]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.compose", description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", required=True)
    parser.add_argument("--path", required=True, type=Path, help="camera path JSON (bench/paths/*.json)")
    parser.add_argument("--tiles", type=int, default=16, help="tiles of sort-first and hybrid")
    parser.add_argument("--size", type=parse_size, default=(1280, 720))
    parser.add_argument("--modes", type=parse_list, default=list(MODES), help="comma-separated, of " + ",".join(MODES))
    parser.add_argument("--depth-strip", type=int, default=DEFAULT_DEPTH_STRIP,
                        help="hybrid border strip, px (default: the coordinator's, from this benchmark's sweep)")
    parser.add_argument("--strips", type=lambda text: [int(v) for v in parse_list(text)], default=[],
                        help="more hybrid strip widths to measure, as rows hybrid:PX")
    parser.add_argument("--nodes", type=int, default=4, help="sort-last nodes")
    parser.add_argument("--speeds", type=parse_speeds, help="sort-last slowdown per node (default all 1)")
    parser.add_argument("--face-limit", type=int, default=DEFAULT_FACE_LIMIT)
    parser.add_argument("--frames", type=int, help="use this many evenly spaced frames of the path")
    parser.add_argument("--json", type=Path, help="write the report here")
    args = parser.parse_args(argv)
    unknown = [m for m in args.modes if m not in MODES]
    if unknown or not args.modes:
        parser.error(f"unknown modes {unknown}; choose from {', '.join(MODES)}")
    if args.tiles < 1 or args.nodes < 1 or args.depth_strip < 0 or any(px < 0 for px in args.strips):
        parser.error("--tiles and --nodes must be >= 1, strips >= 0")
    if args.speeds is not None and len(args.speeds) != args.nodes:
        parser.error(f"--speeds needs {args.nodes} values")
    os.environ["LP_NUM_THREADS"] = "0"
    report = run(args, read_path(args.path, args.frames)[1])
    print_report(report)
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
