"""Picture quality (issue 20): do materials matter, and how much anti-aliasing buys at what cost.

``python -m bench.picture [--scene S …] [--size 1280x720] [--frames 2] [--msaa auto,1,4]
[--still-samples 1,2,4,8,16,32] [--material-size 256x256] [--json OUT]``

- Materials: a smooth gold metal sphere (metallic 1, roughness 0.15) and a rough dielectric sphere
  (metallic 0, roughness 0.9) of the same base colour, each alone in the same frame and camera.
  ``spread_ratio``: the smaller of the two spheres' luminance spreads (5th to 95th percentile of
  Rec. 709 luma over the sphere's pixels) over the larger (1: alike; the metal reflects its
  environment, so its spread is wider); ``colour_distance``: the mean Euclidean RGB distance
  between the two pictures over the sphere's pixels, 8-bit levels.
- Anti-aliasing: per scene (default the diorama, truck and engine and the four scans), ``--frames``
  cameras of an orbit rendered whole at each ``--msaa`` setting (``auto``: the node's default, on
  llvmpipe two samples a pixel drawn twice as wide and :mod:`tessera.antialiasing`'s resolve
  filter, ``msaa`` 0 in the JSON; ``filter``: one sample and the filter, ``msaa`` -1) and,
  as the reference, at 4×4 the size with one sample, box-filtered down to the size (the
  sRGB-encoded values averaged, as the MSAA resolve averages them). Per setting: ``samples``
  (multisamples) drawn, ``paired``, ``filtered``, ``psnr_mean_db`` / ``psnr_min_db`` against that
  reference, ``off16_fraction`` the pixels off by more than 16 levels in any channel, ``frame_ms``
  the mean wall time of a whole frame (draw, resolve, read-back, filter; llvmpipe uses the
  machine's cores, so the load of the machine counts) and ``frame_cpu_ms`` the CPU time of the
  process meanwhile (every llvmpipe thread; less sensitive to other work on the machine). The
  settings of a scene take turns frame by frame, so
  that a change of load touches them alike.
- Progressive still (issues 20, 37): per scene, the same cameras rendered as the still of each
  ``--still-samples`` count (``auto``: the service's adaptive still, which stops where its
  estimated error reaches its target) with the node's default shading (``--msaa auto``), against
  the same reference: ``psnr_mean_db`` / ``psnr_min_db`` / ``off16_fraction`` as above,
  ``samples_mean`` / ``samples_max`` the samples taken, ``estimate_min_db`` the adaptive still's
  least estimate of its PSNR against its converged image, ``frame_ms`` the mean time of one
  sample's frame, ``still_ms`` / ``still_ms_max`` the time of the still's samples (the nodes' time
  until the still converges on one node), mean and most. Each count is rendered apart (its
  samples' texture LOD bias depends on it). Per scene also the coordinator's CPU per sample
  (:class:`server.still_refinement.StillRefiner`'s work on a whole frame, the first camera):
  ``decode_ms`` (of a PNG sample), ``accumulate_ms`` (add and mean), ``encode_ms`` (the converged
  still's PNG), ``refinement_encode_ms`` (a refinement frame's JPEG).
- ``environment_ms``: the environment's prefiltering at start-up (once per process).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import platform
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import moderngl
import numpy as np

from bench.images import psnr, reported_psnr
from bench.paths import make_path
from bench.processes import show_result
from node.gl.context import create_gl_context, renderer_string
from node.gl.image_lighting import prefiltered_environment
from node.gl.renderer import TileRenderer
from node.gl.shading import AUTO_MSAA, FILTER_MSAA, Antialiasing, AntialiasingChoice, ShadingOptions
from node.scene.builtin import place, sphere
from node.scene.data import SceneData
from node.scene.loading import load_scene
from node.scene.material import SurfaceMaterial
from node.settings import parse_msaa, parse_size
from server.still_refinement import REFINEMENT_QUALITY
from tessera.cli_values import parse_still_samples
from tessera.geometry import Camera
from tessera.scheduling.refinement import ADAPTIVE, Accumulator, StillPlan, Subsample, accumulate_still
from tessera.wire.codec import Codec, decode, encode

SHARED_SCENES = Path(__file__).resolve().parents[2] / "shared" / "scenes"
DEFAULT_SCENES = tuple(str(SHARED_SCENES / name) for name in (
    "multi_object/sd_macross_city_diorama.glb", "gltf_small/CesiumMilkTruck/CesiumMilkTruck.gltf",
    "gltf_small/2CylinderEngine.glb", "bunny/bun_zipper.ply", "large_scan/stanford_dragon_vrip_res2_202k.ply",
    "large_scan/stanford_lucy_240k.ply", "large_scan/threedscans_pan_990k.ply"))
#: ``--still-samples`` scenes by default (each count is rendered apart: the scans would take long).
STILL_SCENES = DEFAULT_SCENES[:3]
#: Gold (the glTF spec's metal F0 table), linear.
GOLD = (1.0, 0.766, 0.336)
SMOOTH_METAL = SurfaceMaterial(metallic=1.0, roughness=0.15)
ROUGH_DIELECTRIC = SurfaceMaterial(metallic=0.0, roughness=0.9)
SPHERE_CAMERA = Camera(eye=(0.0, 0.4, 3.2), target=(0.0, 0.0, 0.0), fovy_deg=40.0, near=0.5, far=10.0)
SUPERSAMPLING = 4
OFF_LEVELS = 16


def sphere_scene(material: SurfaceMaterial, base_color: Sequence[float] = GOLD, rows: int = 48) -> SceneData:
    """A unit sphere at the origin of ``base_color`` (linear RGB) and ``material``."""
    batch = place("sphere", sphere(rows, 2 * rows), np.ones(3), np.identity(3), np.zeros(3),
                  (float(base_color[0]), float(base_color[1]), float(base_color[2])))
    return SceneData.from_batches("sphere", [dataclasses.replace(batch, material=material)])


def luma(pixels: np.ndarray) -> np.ndarray:
    """Rec. 709 luma of (…, 3) uint8 sRGB pixels, 0…255 float64."""
    return pixels.astype(np.float64) @ np.array([0.2126, 0.7152, 0.0722])


def material_contrast(ctx: moderngl.Context, size: tuple[int, int], shading: ShadingOptions = ShadingOptions(msaa=1),
                      background: Sequence[float] = (0.0, 0.0, 0.0)) -> dict[str, float]:
    """The smooth metal and rough dielectric spheres compared: spread_ratio, colour_distance and
    each one's ``spread`` (luma levels); one sample per pixel by default, as anti-aliasing would
    mix the silhouettes' pixels with the background's."""
    images = []
    for material in (SMOOTH_METAL, ROUGH_DIELECTRIC):
        renderer = TileRenderer(ctx, sphere_scene(material), background, shading=shading)
        images.append(renderer.render_frame(SPHERE_CAMERA, size).pixels)
        renderer.release()
    mask = (images[0].max(axis=2) > 0) & (images[1].max(axis=2) > 0)
    spreads = [float(np.subtract(*np.percentile(luma(image[mask]), [95, 5]))) for image in images]
    distance = np.linalg.norm(images[0][mask].astype(np.float64) - images[1][mask].astype(np.float64), axis=1)
    return {"metal_spread": spreads[0], "dielectric_spread": spreads[1],
            "spread_ratio": min(spreads) / max(spreads), "colour_distance": float(distance.mean())}


def supersampled(renderer: TileRenderer, camera: Camera, size: tuple[int, int],
                 factor: int = SUPERSAMPLING) -> np.ndarray:
    """(h, w, 3) uint8: ``camera`` rendered at ``factor``× the size with one sample per pixel (the
    renderer's own count and resolve filter are put aside), each factor×factor block averaged
    (summed in integers, then rounded to the nearest level: a 1080p reference's 7680x4320 frame
    never becomes floats)."""
    antialiasing, renderer.antialiasing = renderer.antialiasing, AntialiasingChoice(Antialiasing())
    try:
        large = renderer.render_frame(camera, (size[0] * factor, size[1] * factor)).pixels
    finally:
        renderer.antialiasing = antialiasing
    sums = large.reshape(size[1], factor, size[0], factor, 3).sum(axis=(1, 3), dtype=np.uint32)
    return np.rint(sums / float(factor * factor)).astype(np.uint8)


def orbit_cameras(scene: SceneData, frames: int) -> list[Camera]:
    path = make_path("orbit", scene.bounds, max(frames, 2))
    return [Camera.from_json(camera) for camera in path["frames"][:frames]]


def measure_antialiasing(ctx: moderngl.Context, scene_spec: str, size: tuple[int, int], frames: int,
                         settings: Sequence[int], repeats: int = 3,
                         cameras: Sequence[Camera] | None = None, scene: SceneData | None = None) -> dict[str, Any]:
    """The ``--msaa`` rows of one scene (see the module docstring) at ``cameras`` (None: ``frames``
    of an orbit); each frame is timed ``repeats`` times, the settings in turn. ``scene``: the
    scene already loaded (None: loaded here)."""
    scene = load_scene(scene_spec) if scene is None else scene
    cameras = orbit_cameras(scene, frames) if cameras is None else cameras
    renderers = {msaa: TileRenderer(ctx, scene, shading=ShadingOptions(msaa=msaa)) for msaa in settings}
    found: dict[int, dict[str, list[float]]] = {msaa: {"psnr": [], "off": [], "wall": [], "cpu": []}
                                                for msaa in settings}
    for renderer in renderers.values():
        renderer.render_frame(cameras[0], size)
    for camera in cameras:
        reference = supersampled(renderers[settings[0]], camera, size)
        for _ in range(repeats):
            for msaa, renderer in renderers.items():
                started, started_cpu = time.perf_counter(), time.process_time()
                pixels = renderer.render_frame(camera, size).pixels
                found[msaa]["wall"].append((time.perf_counter() - started) * 1e3)
                found[msaa]["cpu"].append((time.process_time() - started_cpu) * 1e3)
        for msaa, renderer in renderers.items():
            found[msaa]["psnr"].append(psnr(pixels := renderer.render_frame(camera, size).pixels, reference))
            error = np.abs(pixels.astype(np.int16) - reference.astype(np.int16)).max(axis=2)
            found[msaa]["off"].append(float(np.mean(error > OFF_LEVELS)))
    drawn = {msaa: renderer.antialiasing.for_size(size) for msaa, renderer in renderers.items()}
    rows = [{"msaa": msaa, "samples": drawn[msaa].samples, "grid": list(drawn[msaa].grid),
             "paired": drawn[msaa].paired, "filtered": drawn[msaa].filtered,
             "psnr_mean_db": reported_psnr(float(np.mean(found[msaa]["psnr"]))),
             "psnr_min_db": reported_psnr(float(np.min(found[msaa]["psnr"]))),
             "off16_fraction": float(np.mean(found[msaa]["off"])), "frame_ms": float(np.median(found[msaa]["wall"])),
             "frame_cpu_ms": float(np.median(found[msaa]["cpu"]))} for msaa, renderer in renderers.items()]
    for renderer in renderers.values():
        renderer.release()
    return {"scene": scene_spec, "size": list(size), "frames": len(cameras), "rows": rows}


def still_plan(count: int) -> StillPlan:
    """A ``--still-samples`` count as the service samples it (0, :data:`ADAPTIVE`: its default
    adaptive still)."""
    return StillPlan(count) if count != ADAPTIVE else StillPlan(ADAPTIVE)


def measure_still(ctx: moderngl.Context, scene_spec: str, size: tuple[int, int], frames: int,
                  sample_counts: Sequence[int], cameras: Sequence[Camera] | None = None,
                  scene: SceneData | None = None) -> dict[str, Any]:
    """The progressive still rows of one scene (see the module docstring) at ``cameras`` (None:
    ``frames`` of an orbit); a count of :data:`ADAPTIVE` is the service's adaptive still (its
    ``samples_mean`` / ``samples_max`` taken, ``estimate_min_db`` its least estimate). The
    coordinator's costs are measured on the first camera's samples."""
    scene = load_scene(scene_spec) if scene is None else scene
    cameras = orbit_cameras(scene, frames) if cameras is None else cameras
    renderer = TileRenderer(ctx, scene)
    found: dict[int, dict[str, list[float]]] = {n: {"psnr": [], "off": [], "taken": [], "estimate": [], "ms": []}
                                                for n in sample_counts}
    frame_ms: list[float] = []
    coordinator: dict[str, list[float]] = {"decode_ms": [], "accumulate_ms": [], "encode_ms": [],
                                           "refinement_encode_ms": []}
    renderer.render_frame(cameras[0], size)

    def draw(camera: Camera, sample: Subsample | None, timed: list[float]) -> np.ndarray:
        started = time.perf_counter()
        pixels = renderer.render_frame(camera, size, subsample=sample).pixels
        timed.append((time.perf_counter() - started) * 1e3)
        return pixels

    for index, camera in enumerate(cameras):
        reference = supersampled(renderer, camera, size)
        for count in sample_counts:
            timed: list[float] = []
            accumulator = accumulate_still(lambda sample, timed=timed: draw(camera, sample, timed), size,  # noqa: B023
                                           still_plan(count))
            still = accumulator.mean()
            frame_ms += timed
            found[count]["psnr"].append(psnr(still, reference))
            found[count]["taken"].append(accumulator.count)
            found[count]["ms"].append(sum(timed))
            if accumulator.estimate_db is not None:
                found[count]["estimate"].append(accumulator.estimate_db)
            error = np.abs(still.astype(np.int16) - reference.astype(np.int16)).max(axis=2)
            found[count]["off"].append(float(np.mean(error > OFF_LEVELS)))
            if index == 0 and count == sample_counts[-1]:
                coordinator_costs(renderer, camera, size, still_plan(count), coordinator)
    sample_ms = float(np.mean(frame_ms))
    rows = [{"samples": count, "adaptive": count == ADAPTIVE,
             "psnr_mean_db": reported_psnr(float(np.mean(found[count]["psnr"]))),
             "psnr_min_db": reported_psnr(float(np.min(found[count]["psnr"]))),
             "off16_fraction": float(np.mean(found[count]["off"])), "frame_ms": sample_ms,
             "samples_mean": float(np.mean(found[count]["taken"])), "samples_max": int(max(found[count]["taken"])),
             "estimate_min_db": reported_psnr(min(found[count]["estimate"])) if found[count]["estimate"] else None,
             "still_ms": float(np.mean(found[count]["ms"])), "still_ms_max": float(max(found[count]["ms"]))}
            for count in sample_counts]
    renderer.release()
    return {"scene": scene_spec, "size": list(size), "frames": len(cameras),
            "msaa": renderer.antialiasing.for_size(size).samples, "rows": rows,
            "coordinator": {key: float(np.mean(values)) for key, values in coordinator.items()}}


def coordinator_costs(renderer: TileRenderer, camera: Camera, size: tuple[int, int], plan: StillPlan,
                      costs: dict[str, list[float]]) -> None:
    """The coordinator's CPU per sample of ``plan``'s still at ``camera``
    (:class:`server.still_refinement.StillRefiner`'s work on a whole frame), appended to ``costs``."""
    accumulator = Accumulator(size, plan)
    while not accumulator.converged:
        pixels = renderer.render_frame(camera, size, subsample=plan.subsample(accumulator.count)).pixels
        decoded, spent = cpu_ms(decode, encode(pixels, Codec.PNG), Codec.PNG, size[0], size[1])
        costs["decode_ms"].append(spent)
        started_cpu = time.thread_time()
        accumulator.add(decoded)
        accumulator.finish_sample()
        still = accumulator.mean()
        costs["accumulate_ms"].append((time.thread_time() - started_cpu) * 1e3)
        costs["encode_ms"].append(cpu_ms(encode, still, Codec.PNG)[1])
        costs["refinement_encode_ms"].append(cpu_ms(encode, still, Codec.JPEG, REFINEMENT_QUALITY)[1])


def cpu_ms(call: Callable[..., Any], *args: Any) -> tuple[Any, float]:
    """``call(*args)``'s result and the CPU time of this thread it took, ms."""
    started = time.thread_time()
    result = call(*args)
    return result, (time.thread_time() - started) * 1e3


def parse_still_counts(text: str) -> list[int]:
    """``--still-samples``: counts 1…:data:`MAX_STILL_SAMPLES` and ``auto`` (:data:`ADAPTIVE`, listed first)."""
    counts = sorted({parse_still_samples(part) for part in text.split(",") if part.strip()})
    if not counts:
        raise argparse.ArgumentTypeError(f"no still sample count given in {text!r}")
    return counts


def parse_counts(text: str) -> list[int]:
    """``--msaa`` settings, each as the node's ``--msaa`` takes it (auto, filter, 1, 2, 4, 8), in the
    order given."""
    counts: list[int] = []
    for part in (part.strip() for part in text.split(",") if part.strip()):
        count = parse_msaa(part)
        if count not in counts:
            counts.append(count)
    if not counts:
        raise argparse.ArgumentTypeError("no msaa setting given")
    return counts


def drawn_name(row: dict[str, Any]) -> str:
    """What a row's frames were drawn with, as the table shows it: '1', '4', '1+f' (one sample,
    filtered), '2w+f' (two samples drawn twice as wide, filtered), '3x3' (a grid of samples)."""
    grid = row.get("grid") or [1, 1]
    drawn = "2w" if row.get("paired") else f"{grid[0]}x{grid[1]}" if grid != [1, 1] else str(row["samples"])
    return drawn + ("+f" if row.get("filtered") else "")


def setting_name(row: dict[str, Any]) -> str:
    """A ``--msaa`` row's setting as the table shows it: :func:`drawn_name` after 'auto' or 'filter'
    where the row's ``msaa`` was one of those."""
    named = {AUTO_MSAA: "auto ", FILTER_MSAA: "filter "}
    return named.get(row["msaa"], "") + drawn_name(row)


def table(result: dict[str, Any]) -> str:
    materials = result["materials"]
    lines = [f"materials: spread ratio {materials['spread_ratio']:.2f}, colour distance "
             f"{materials['colour_distance']:.1f} levels (metal spread {materials['metal_spread']:.1f}, "
             f"dielectric {materials['dielectric_spread']:.1f}); environment prefiltered in "
             f"{result['environment_ms']:.0f} ms", antialiasing_table(result["scenes"])]
    if result.get("stills"):
        lines.append(still_table(result["stills"]))
    return "\n".join(lines)


def scene_label(result: dict[str, Any]) -> str:
    """A scene's name with its frame size when the result has one: 'bun_zipper.ply 640x360'."""
    size = result.get("size")
    return Path(result["scene"]).name + (f" {size[0]}x{size[1]}" if size else "")


def antialiasing_table(scenes: Sequence[dict[str, Any]]) -> str:
    """The ``--msaa`` rows of :func:`measure_antialiasing`'s ``scenes``, one line each."""
    lines = [f"{'scene':<44} {'msaa':>8} {'PSNR dB':>8} {'min':>6} {'off>16':>7} {'frame ms':>9} {'CPU ms':>7}"]
    for scene in scenes:
        for row in scene["rows"]:
            lines.append(f"{scene_label(scene):<44} {setting_name(row):>8} {row['psnr_mean_db']:>8.2f} "
                         f"{row['psnr_min_db']:>6.2f} {row['off16_fraction'] * 100:>6.2f}% {row['frame_ms']:>9.1f} "
                         f"{row.get('frame_cpu_ms', math.nan):>7.1f}")
    return "\n".join(lines)


def still_table(stills: Sequence[dict[str, Any]]) -> str:
    """The rows of :func:`measure_still`'s ``stills``, one line each, and the coordinator's cost:
    N (``auto``: the adaptive still, then the samples it took, mean and most), PSNR mean and worst,
    the least estimate, a sample's frame ms, the still's ms on one node (mean and most)."""
    lines = [f"{'progressive still':<44} {'N':>4} {'taken':>9} {'PSNR dB':>8} {'min':>6} {'est min':>7} {'off>16':>7} "
             f"{'frame ms':>9} {'still ms':>9} {'max':>6}"]
    for scene in stills:
        for row in scene["rows"]:
            drawn = drawn_name({"samples": scene["msaa"]})
            taken = f"{row.get('samples_mean', row['samples']):.1f}/{row.get('samples_max', row['samples'])}"
            estimate = row.get("estimate_min_db")
            lines.append(f"{scene_label(scene) + ' (msaa ' + drawn + ')':<44} "
                         f"{'auto' if row.get('adaptive') else row['samples']:>4} {taken:>9} "
                         f"{row['psnr_mean_db']:>8.2f} {row['psnr_min_db']:>6.2f} "
                         f"{'-' if estimate is None else f'{estimate:.1f}':>7} {row['off16_fraction'] * 100:>6.2f}% "
                         f"{row['frame_ms']:>9.1f} {row['still_ms']:>9.0f} {row.get('still_ms_max', math.nan):>6.0f}")
        cost = scene["coordinator"]
        if cost:
            lines.append(f"  coordinator CPU per sample: decode {cost['decode_ms']:.1f} ms, accumulate "
                         f"{cost['accumulate_ms']:.1f} ms, encode {cost['encode_ms']:.1f} ms (PNG) or "
                         f"{cost['refinement_encode_ms']:.1f} ms (a refinement's JPEG)")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.picture", description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", action="append",
                        help="scene (repeatable; default diorama, truck, engine and the four scans; the still rows "
                             "of the first three)")
    parser.add_argument("--size", type=parse_size, default=(1280, 720))
    parser.add_argument("--frames", type=int, default=2)
    parser.add_argument("--msaa", type=parse_counts, default=[AUTO_MSAA, FILTER_MSAA, 1, 4],
                        help="settings compared, of auto, filter, 1, 2, 4, 8 (default auto,filter,1,4)")
    parser.add_argument("--still-samples", type=parse_still_counts, default=[ADAPTIVE, 1, 2, 4, 8, 16, 32],
                        help="progressive still sample counts, auto the adaptive still (default auto,1,2,4,8,16,32)")
    parser.add_argument("--material-size", type=parse_size, default=(256, 256))
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    started = time.perf_counter()
    prefiltered_environment.cache_clear()
    environment_ms = prefiltered_environment(None).prefilter_ms
    ctx = create_gl_context()
    try:
        result: dict[str, Any] = {
            "meta": {"renderer": renderer_string(ctx), "python": platform.python_version(), "size": list(args.size),
                     "argv": list(sys.argv[1:] if argv is None else argv)},
            "environment_ms": environment_ms,
            "materials": material_contrast(ctx, args.material_size),
            "scenes": [measure_antialiasing(ctx, scene, args.size, args.frames, args.msaa)
                       for scene in (args.scene or DEFAULT_SCENES)],
            "stills": [measure_still(ctx, scene, args.size, args.frames, args.still_samples)
                       for scene in (args.scene or STILL_SCENES)],
        }
    finally:
        ctx.release()
    result["meta"]["wall_s"] = time.perf_counter() - started
    show_result(table(result), result, args.json, argv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
