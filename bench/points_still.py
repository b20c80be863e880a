"""A point cloud's still in one process (issue 36): what the still's spacing on screen
(:data:`tessera.points.budget.STILL_SPACING_PX`) costs and changes against the still of every point.

``python -m bench.points_still --cloud PATH [--cache DIR] [--size 1280x720] [--spacings 0.25,0.5,1]
[--paths oblique,ground] [--samples 8] [--json OUT]``

The cloud's scene cache entry is built (or found in ``--cache``) and drawn by one
:class:`node.gl.point_renderer.PointRenderer` as ``--render-once`` draws a still: for each camera of
``--paths`` (``bench.points``' cameras, turned 1 radian), a still of a fixed ``--samples`` jittered
samples of every point in view (spacing 0), then one at each of ``--spacings`` (pixels; the
spacing alone, where the still as shipped draws every point up to
:data:`tessera.points.budget.STILL_EVERY_POINT_MAX` in view): the points
a sample draws, the CPU seconds a sample costs (this process, all its threads: llvmpipe's too) and
the PSNR of that still against the still of every point.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench.images import psnr, reported_psnr
from bench.points import PATHS, oblique, parse_paths
from bench.processes import show_result
from tessera.cli_values import size_parser
from tessera.geometry import Camera
from tessera.scheduling.refinement import StillPlan, accumulate_still


def still(
    renderer: Any, camera: Camera, size: tuple[int, int], samples: int, spacing_px: float
) -> tuple[np.ndarray, int, float]:
    """(the still's (h, w, 3) uint8 picture, points a sample drew, CPU s a sample) at ``spacing_px``."""
    renderer.still_spacing_px = spacing_px
    renderer.still_every_point_max = 0     # the spacing alone, however few the points in view
    drawn: list[int] = []

    def sample(subsample: Any) -> np.ndarray:
        frame = renderer.render_frame(camera, size, subsample=subsample)
        drawn.append(frame.points)
        return frame.pixels

    started = time.process_time()
    picture = accumulate_still(sample, size, StillPlan(samples)).mean()
    return picture, int(np.median(drawn)), (time.process_time() - started) / samples


def measure(args: argparse.Namespace) -> dict[str, Any]:
    from node.gl.context import create_gl_context
    from node.gl.point_renderer import PointRenderer
    from node.scene.cache_folder import CacheFolder
    from node.scene.point_cache import cached_points, open_points_entry

    cloud_path = Path(args.cloud).resolve()
    cache = Path(args.cache or tempfile.mkdtemp(prefix="tessera-points-still-"))
    entry = cached_points(cloud_path, None, CacheFolder(cache, 1 << 50), lambda fraction, message: None)
    cloud = open_points_entry(entry, cloud_path.name, verify=False)
    renderer = PointRenderer(create_gl_context(), cloud)
    bounds = cloud.bounds.tolist()
    rows = []
    for path in args.paths:
        camera = Camera(**oblique(bounds, 1.0, path))
        reference, every, every_cpu = still(renderer, camera, args.size, args.samples, 0.0)
        for spacing in args.spacings:
            picture, points, cpu = still(renderer, camera, args.size, args.samples, spacing)
            rows.append(
                {
                    "path": path,
                    "spacing_px": spacing,
                    "points": points,
                    "cpu_s": round(cpu, 2),
                    "every_points": every,
                    "every_cpu_s": round(every_cpu, 2),
                    "psnr_db": reported_psnr(psnr(picture, reference)),
                    "load": round(os.getloadavg()[0], 1),
                }
            )
            print(rows[-1], file=sys.stderr, flush=True)
    return {
        "cloud": cloud_path.name,
        "points": cloud.point_count,
        "size": list(args.size),
        "samples": args.samples,
        "rows": rows,
    }


def report(result: dict[str, Any]) -> str:
    lines = [
        f"{result['cloud']}: {result['points']} points, {result['size'][0]}x{result['size'][1]}, stills of "
        f"{result['samples']} samples",
        f"{'path':>9} {'spacing':>8} {'points':>10} {'CPU s':>6} {'every':>10} {'CPU s':>6} {'PSNR':>6} {'load':>5}",
    ]
    for row in result["rows"]:
        db = row["psnr_db"]
        lines.append(
            f"{row['path']:>9} {row['spacing_px']:>8g} {row['points']:>10} {row['cpu_s']:>6} "
            f"{row['every_points']:>10} {row['every_cpu_s']:>6} "
            f"{'inf' if db is None or math.isinf(db) else db:>6} {row['load']:>5}"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.points_still", description=__doc__.split("\n\n")[0])
    parser.add_argument("--cloud", required=True, help="a point cloud file (LAS, LAZ, PLY without faces)")
    parser.add_argument("--cache", help="a scene cache folder (default: a new one)")
    parser.add_argument("--size", type=size_parser(16, 8192), default=(1280, 720))
    parser.add_argument("--spacings", type=lambda text: [float(v) for v in text.split(",")], default=[0.25, 0.5, 1.0])
    parser.add_argument(
        "--paths",
        type=parse_paths,
        default=["oblique", "ground"],
        help=f"camera paths, of {', '.join(PATHS)} (default oblique,ground)",
    )
    parser.add_argument("--samples", type=int, default=8)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    result = measure(args)
    show_result(report(result), result, args.json, argv if argv is not None else sys.argv[1:])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
