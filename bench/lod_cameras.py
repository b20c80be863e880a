"""The moving frame's picture at levels of detail from many cameras (issue 32): where it loses PSNR.

``python -m bench.lod_cameras --scene FILE [--cache-dir DIR] [--size 1280x720] [--bounds 1,1.5]
[--orbit 8] [--near 4] [--quality 60] [--still-samples 0] [--classes] [--json OUT]``

The scene and its levels come from the scene cache as a node reads them (built there first if need
be: a big model's levels take minutes). In one process, a :class:`node.gl.renderer.TileRenderer`
with its defaults draws whole frames (the moving frame's anti-aliasing) from ``--orbit`` cameras
around the default one (:func:`bench.paths.orbit_around`, one turn) and ``--near`` more at half its
distance, a quarter turn apart from 20°. Per camera: the full-detail frame; ``codec_db``, its JPEG
at ``--quality`` (the interactive codec's default) against it; and per bound of ``--bounds`` (pixels,
as ``--lod-error-px``): the triangles drawn, ``levels_db`` the frame at that bound against full
detail, ``moving_db`` its JPEG against full detail (what ``bench.bigscene`` measures of a session's
moving frame), ``pipeline_db`` its JPEG against the full-detail frame's JPEG at the same quality (the
moving frame a user gets with levels against the one they would get without: same anti-aliasing,
same codec) and ``silhouette_share``, the part of the levels' squared error on the model's pixels
within one pixel of the background in either frame (``silhouette_px``: their share of the frame's
pixels); the rest is the inside of the model, its shading. With ``--still-samples N``, both frames
are compared with the converged picture too, the still of N jittered samples at full detail
(:meth:`node.gl.renderer.TileRenderer.render_still`): ``full_still_db`` and, per bound, ``still_db``
(the full-detail moving frame is aliased where triangles are smaller than pixels: how much of the
levels' difference is picture lost, not aliasing changed). With ``--classes``, per bound ``classes``:
the levels' squared error by the kind of pixel it lies on (outline, depth step inside the model,
surface grazing, oblique or facing the eye: :mod:`bench.error_classes`, from the full-detail
frame's depth), the PSNR over the model's pixels alone and their mean signed difference. The last
lines give the worst camera of each figure and how many cameras keep :data:`GOAL_DB` (``worst`` in
the JSON).
"""

from __future__ import annotations

import argparse
import io
import json
import math
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from bench.error_classes import CLASSES, classify, dilate, error_shares
from bench.images import psnr
from bench.paths import orbit_around
from node.gl.context import create_gl_context
from node.gl.renderer import TileRenderer
from node.scene.cache_folder import CacheFolder
from node.scene.data import SceneData
from node.scene.fetch import DEFAULT_CACHE_DIR
from node.scene.ingest import cached_levels, open_cached, read_scene
from node.scene.lod import read_lod
from node.scene.octree import DEFAULT_FACE_LIMIT
from tessera.cli_values import size_parser
from tessera.geometry import Camera, Rect, default_camera, near_far_from_bounds
from tessera.scheduling.config import SchedulerConfig
from tessera.wire.codec import Codec, encode

#: The issue's goal for the moving frame against full detail (dB).
GOAL_DB = 38.0


def cameras(scene: SceneData, size: tuple[int, int], orbit: int, near: int) -> list[tuple[str, Camera]]:
    """:func:`cameras_around` the scene's default camera for frames of ``size``."""
    return cameras_around(default_camera(scene.bounds, aspect=size[0] / size[1]), orbit, near)


def cameras_around(base: Camera, orbit: int, near: int) -> list[tuple[str, Camera]]:
    """``orbit`` cameras on one turn around ``base``'s target at its distance (the first ``base``
    itself), then ``near`` at half the distance, a quarter turn apart from 20°: (name, camera)."""
    around = [Camera.from_json(c) for c in orbit_around(base, orbit)["frames"]] if orbit else []
    named = [(f"orbit {round(360 * k / orbit)}°", camera) for k, camera in enumerate(around)]
    eye, target = np.asarray(base.eye, np.float64), np.asarray(base.target, np.float64)
    for k in range(near):
        angle = math.radians(20 + 90 * k)
        c, s = math.cos(angle), math.sin(angle)
        offset = (eye - target) * 0.5
        turned = np.array([c * offset[0] + s * offset[2], offset[1], -s * offset[0] + c * offset[2]])
        named.append((f"half {20 + 90 * k}°", Camera(eye=tuple((target + turned).tolist()), target=base.target,
                                                     up=base.up, fovy_deg=base.fovy_deg)))
    return named


def jpeg(pixels: np.ndarray, quality: int) -> np.ndarray:
    """``pixels`` (h, w, 3) uint8 through the interactive codec at ``quality`` and back."""
    return np.asarray(Image.open(io.BytesIO(encode(pixels, Codec.JPEG, quality))).convert("RGB"))


def silhouette(pixels: np.ndarray, background: np.ndarray) -> np.ndarray:
    """(h, w) bool the pixels of the model (not ``background`` (3,) uint8) within one pixel (3 × 3)
    of a background pixel."""
    empty = np.all(pixels == background, axis=2)
    return dilate(empty, 1) & ~empty


def pixel_classes(renderer: TileRenderer, camera: Camera, size: tuple[int, int], full: np.ndarray,
                  background: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """For the full-detail frame ``full`` (h, w, 3) uint8 of ``camera``: the class of each pixel
    (:func:`bench.error_classes.classify`) against another frame's pixels, from the depth of a
    full-detail layer (one sample a pixel)."""
    depth = renderer.render_layer(camera, size, Rect(0, 0, *size)).depth
    assert depth is not None
    near, far = near_far_from_bounds(camera, renderer.pose_of(None).bounds)
    empty = np.all(full == background, axis=2)
    return lambda pixels: classify(depth, empty, np.all(pixels == background, axis=2), near, far, camera.fovy_deg)


def measure(args: argparse.Namespace) -> dict[str, Any]:
    folder = CacheFolder(args.cache_dir, 1 << 40)
    progress = lambda fraction, message: None  # noqa: E731
    made = read_scene(str(args.scene), str(args.scene), DEFAULT_FACE_LIMIT, None, progress, folder)
    scene = open_cached(made, str(args.scene))
    assert isinstance(scene, SceneData) and isinstance(made, Path), "a mesh file"
    levels = cached_levels(made, folder, progress)
    if levels is None:
        raise SystemExit(f"{args.scene}: no batch big enough for levels of detail")
    ctx = create_gl_context()
    renderer = TileRenderer(ctx, scene, packed=scene.geometry)
    renderer.attach_lod(read_lod(levels))
    background = np.round(np.asarray(renderer.background) * 255.0).astype(np.uint8)
    rows = []
    for name, camera in cameras(scene, args.size, args.orbit, args.near):
        full = renderer.render_frame(camera, args.size).pixels
        full_jpeg = jpeg(full, args.quality)
        row: dict[str, Any] = {"camera": name, "codec_db": round(psnr(full_jpeg, full), 2)}
        still = renderer.render_still(camera, args.size, args.still_samples) if args.still_samples else None
        classes_of = pixel_classes(renderer, camera, args.size, full, background) if args.classes else None
        if still is not None:
            row["full_still_db"] = round(psnr(full, still), 2)
        for bound in args.bounds:
            frame = renderer.render_frame(camera, args.size, lod_error_px=bound)
            error = ((frame.pixels.astype(np.float64) - full) ** 2).sum(axis=2)
            edge = silhouette(full, background) | silhouette(frame.pixels, background)
            moving = jpeg(frame.pixels, args.quality)
            row[f"{bound:g}px"] = {
                "triangles": frame.triangles, "levels_db": round(psnr(frame.pixels, full), 2),
                "moving_db": round(psnr(moving, full), 2), "pipeline_db": round(psnr(moving, full_jpeg), 2),
                "silhouette_share": round(float(error[edge].sum() / max(error.sum(), 1.0)), 3),
                "silhouette_px": round(float(edge.mean()), 4)}
            if still is not None:
                row[f"{bound:g}px"]["still_db"] = round(psnr(frame.pixels, still), 2)
            if classes_of is not None:
                row[f"{bound:g}px"]["classes"] = error_shares(frame.pixels, full, classes_of(frame.pixels))
        rows.append(row)
        print(report_row(row), flush=True)
    renderer.release()
    ctx.release()
    summary = worst(rows)
    print(report_worst(summary), flush=True)
    return {"scene": str(args.scene), "size": list(args.size), "quality": args.quality, "cameras": rows,
            "worst": summary}


def worst(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Of :func:`measure`'s camera rows: per figure (``codec_db``, and per bound ``levels_db``,
    ``moving_db``, ``pipeline_db``, ``still_db`` where measured) the worst camera's dB and name and
    how many cameras keep :data:`GOAL_DB`; per bound the most triangles a camera drew."""
    def least(values: list[tuple[float, str]]) -> dict[str, Any]:
        db, camera = min(values)
        return {"db": db, "camera": camera, "at_goal": sum(v >= GOAL_DB for v, _ in values), "of": len(values)}

    summary: dict[str, Any] = {"codec_db": least([(row["codec_db"], row["camera"]) for row in rows])}
    for key in [k for k, v in rows[0].items() if isinstance(v, dict)] if rows else ():
        figures = [k for k in ("levels_db", "moving_db", "pipeline_db", "still_db") if k in rows[0][key]]
        summary[key] = {figure: least([(row[key][figure], row["camera"]) for row in rows]) for figure in figures}
        summary[key]["max_triangles"] = max(row[key]["triangles"] for row in rows)
    return summary


def report_worst(summary: dict[str, Any]) -> str:
    """:func:`worst`'s figures, a line each."""
    def text(least: dict[str, Any]) -> str:
        return f"{least['db']:5.1f} dB ({least['camera']}), {least['at_goal']}/{least['of']} cameras >= {GOAL_DB:g}"

    lines = [f"worst camera: JPEG alone {text(summary['codec_db'])}"]
    for key, figures in summary.items():
        if key != "codec_db":
            lines.append(f"  {key} ({figures['max_triangles'] / 1e6:.2f}M tri at most): "
                         + "; ".join(f"{figure} {text(least)}" for figure, least in figures.items()
                                     if isinstance(least, dict)))
    return "\n".join(lines)


def report_row(row: dict[str, Any]) -> str:
    parts = [f"{row['camera']:>10}: JPEG alone {row['codec_db']:5.1f} dB"]
    if "full_still_db" in row:
        parts.append(f"full detail {row['full_still_db']:5.1f} dB from the still")
    for key, value in row.items():
        if isinstance(value, dict):
            parts.append(f"{key} {value['triangles'] / 1e6:.2f}M tri, levels {value['levels_db']:5.1f} dB, "
                         f"after JPEG {value['moving_db']:5.1f} dB, JPEG against JPEG {value['pipeline_db']:5.1f} dB, "
                         f"silhouettes {value['silhouette_share']:.0%} "
                         f"of the error on {value['silhouette_px']:.1%} of the pixels"
                         + (f", {value['still_db']:5.1f} dB from the still" if "still_db" in value else "")
                         + (f"; {report_classes(value['classes'])}" if "classes" in value else ""))
    return " | ".join(parts)


def report_classes(shares: dict[str, Any]) -> str:
    """:func:`bench.error_classes.error_shares`' figures in a few words."""
    return (", ".join(f"{name} {shares[name]['error']:.0%} on {shares[name]['pixels']:.1%}" for name in CLASSES)
            + f" (error on pixels); the model's pixels {shares['model_db']:.1f} dB, mean {shares['mean']:+.2f}")


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.lod_cameras", description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", type=Path, required=True, help="a mesh file (PLY, glTF, …)")
    parser.add_argument("--cache-dir", type=Path, default=DEFAULT_CACHE_DIR,
                        help=f"the scene cache folder (default {DEFAULT_CACHE_DIR}, the nodes')")
    parser.add_argument("--size", type=size_parser(16, 16384), default=(1280, 720), help="the frames' size")
    parser.add_argument("--bounds", type=lambda text: [float(v) for v in text.split(",")], default=[1.0, 1.5],
                        help="error bounds in pixels (as --lod-error-px)")
    parser.add_argument("--orbit", type=int, default=8, help="cameras on a turn around the default one")
    parser.add_argument("--near", type=int, default=4, help="cameras at half the default one's distance")
    parser.add_argument("--quality", type=int, default=SchedulerConfig().interactive_quality,
                        help="JPEG quality of the moving frame (default: the interactive codec's)")
    parser.add_argument("--still-samples", type=int, default=0,
                        help="compare with the still of this many samples at full detail too (0: not)")
    parser.add_argument("--classes", action="store_true",
                        help="split each bound's error by the kind of pixel it lies on (outline, depth step, facing)")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    result = measure(args)
    if args.json:
        args.json.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
