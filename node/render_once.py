"""``python -m node --render-once OUT.png``: one full frame rendered alone, no coordinator — the
reference image every composited frame is checked against. ``--face-limit`` and ``--culling`` apply
as on a serving node; neither changes the image. ``--msaa`` and ``--environment`` shade as on a
serving node (a hybrid or sort-last frame, drawn at one sample, equals ``--msaa 1``).

Without ``--interactive`` the image is the progressive still (issues 20, 37) the live service
converges to with its defaults: whole frames, each shifted by its sample's jitter, accumulated
exactly as the coordinator does and until the same estimate says it converged (``--samples auto``,
``--samples-max``, ``--target-db``: the coordinator's ``--still-samples``, ``--still-samples-max``,
``--still-target-db`` defaults), or ``--samples N`` of them
(:func:`tessera.scheduling.refinement.accumulate_still`). ``--interactive``: the interactive frame,
one sample, not shifted (what ``--samples 1`` also gives).

The frame shows the scene state (issue 11) at ``--time T`` seconds (default 0): the scene's
animations sampled at T, then the poses of ``--objects STATE.json``, ``{name: {"translation",
"rotation", "scale", "visible"}}`` with any subset of those fields per object; ``--clip CLIP.json``
cuts it by clip planes and a section box (issue 35, as ``PUT /api/sessions/{id}/clip`` takes them)
and ``--highlight NAME`` draws an object selected."""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import moderngl
import numpy as np

from node.culling.tiles import CullingUnavailableError
from node.gl.context import GLUnavailableError, create_gl_context
from node.gl.environment import EnvironmentError
from node.gl.point_renderer import PointRenderer
from node.gl.renderer import TileRenderer
from node.gl.shading import Antialiasing
from node.gl.view_tools import ViewTools
from node.scene.data import SceneData
from node.scene.ingest import cached_levels, open_cached, read_scene
from node.scene.lod import read_lod
from node.scene.mesh import SceneError
from node.scene.points import PointCloud
from node.settings import NodeSettings
from tessera.geometry import Camera, CameraError, default_camera
from tessera.scene.state import ObjectPatch, SceneState, SceneStateError, UnknownObjectError
from tessera.scheduling.refinement import Subsample, accumulate_still
from tessera.scheduling.render_jobs import windows
from tessera.tools.clipping import ClipError, ClipState
from tessera.wire.codec import encode_png

T = TypeVar("T")
E = TypeVar("E", bound=Exception)


def read_json(path: Path, what: str, error: type[Exception]) -> Any:
    """The JSON in ``path``; raises ``error`` naming ``what`` file, the path and the reason."""
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise error(f"{what} file {path}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise error(f"{what} file {path}: unreadable ({exc})") from None
    except ValueError as exc:
        raise error(f"{what} file {path}: invalid JSON ({exc})") from None


def read_parsed(path: Path, what: str, error: type[E], parse: Callable[[Any], T]) -> T:
    """``parse`` of the JSON in ``path``; raises ``error`` naming ``what`` file, the path and the
    reason (``parse`` raises ``error`` for content it refuses)."""
    data = read_json(path, what, error)
    try:
        return parse(data)
    except error as exc:
        raise error(f"{what} file {path}: {exc}") from None


def read_camera(path: Path) -> Camera:
    """Parse a camera JSON file: a camera, or the coordinator's answer to ``GET /api/camera``
    (``{"camera": …, "frame": …}``) as saved; raises CameraError whose message names the file and
    the reason."""

    def camera(data: Any) -> Camera:
        answer = isinstance(data, dict) and isinstance(data.get("camera"), dict) and "eye" not in data
        return Camera.from_json(data["camera"] if answer else data)

    return read_parsed(path, "camera", CameraError, camera)


def read_objects(path: Path) -> dict[str, ObjectPatch]:
    """Parse an object state file; raises SceneStateError whose message names the file and the reason."""

    def patches(data: Any) -> dict[str, ObjectPatch]:
        if not isinstance(data, dict):
            raise SceneStateError("must be a JSON object of name: state")
        return {str(name): ObjectPatch.from_json(value, str(name)) for name, value in data.items()}

    return read_parsed(path, "objects", SceneStateError, patches)


def read_clip(path: Path) -> ClipState:
    """Parse a clip state file; raises ClipError whose message names the file and the reason."""
    return read_parsed(path, "clip", ClipError, ClipState.from_json)


def render_once(settings: NodeSettings) -> int:
    """Render ``settings.scene`` to ``settings.render_once`` (PNG); returns the exit code and
    prints one ``error: …`` line on failure."""
    assert settings.render_once is not None
    try:
        camera = read_camera(settings.camera) if settings.camera is not None else None
        overrides = read_objects(settings.objects) if settings.objects is not None else None
        clip = read_clip(settings.clip) if settings.clip is not None else None
        made = read_scene(settings.scene, settings.scene, settings.face_limit, None, lambda fraction, message: None,
                          settings.cache)
        scene = open_cached(made, settings.scene)
        camera = camera or default_camera(scene.bounds)
        if isinstance(scene, PointCloud):
            return _render_points(settings, scene, camera)
        state = _state(scene, settings.time, overrides, settings.objects)
        ctx = create_gl_context()
        renderer = TileRenderer(ctx, scene, settings.background, culling=settings.culling, shading=settings.shading,
                                packed=scene.geometry)
        if settings.highlight is not None:
            scene.objects.lookup(settings.highlight)
        renderer.use_tools(ViewTools(clip, settings.highlight))
        if settings.interactive and settings.lod_error_px > 0.0 and isinstance(made, Path):
            levels = cached_levels(made, settings.cache, lambda fraction, message: None)
            if levels is not None:
                renderer.attach_lod(read_lod(levels))
        started = time.perf_counter()
        if settings.interactive:
            if len(windows(settings.size)) == 1:
                frame = renderer.render_frame(camera, settings.size, state, lod_error_px=settings.lod_error_px)
                pixels, drawn = frame.pixels, f"{frame.triangles} drawn, {frame.cull_path} culling"
            else:
                pixels, drawn = draw_picture(renderer, camera, settings.size, state, None), "by windows"
            samples = 1
        else:
            still = accumulate_still(lambda subsample: draw_picture(renderer, camera, settings.size, state, subsample),
                                     settings.size, settings.still_plan)
            pixels, samples = still.mean(), still.count
            estimate = "" if still.estimate_db is None else f", estimated {min(still.estimate_db, 100.0):.1f} dB " \
                "from its converged image"
            drawn = f"{samples} jittered sample{'s' if samples > 1 else ''}{estimate}"
        render_ms = (time.perf_counter() - started) * 1e3
        settings.render_once.write_bytes(encode_png(pixels))
    except (CameraError, SceneError, SceneStateError, ClipError, GLUnavailableError, CullingUnavailableError,
            EnvironmentError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except moderngl.Error as exc:
        print(f"error: GL failed: {' '.join(str(exc).split())}", file=sys.stderr)
        return 1
    except OSError as exc:
        print(f"error: cannot write {settings.render_once}: {exc.strerror or exc}", file=sys.stderr)
        return 1
    width, height = settings.size
    kind = "interactive frame" if settings.interactive else "still"
    drawn_with = renderer.antialiasing.for_size(settings.size)
    antialiasing = (drawn_with if settings.interactive else Antialiasing(drawn_with.samples)).label
    print(f"wrote {settings.render_once} ({kind}, {width}x{height}, {scene.triangle_count} triangles in "
          f"{scene.chunks.chunk_count} chunks, {drawn}, {antialiasing}, render {render_ms:.1f} ms)")
    return 0


def draw_picture(renderer: TileRenderer, camera: Camera, size: tuple[int, int], state: SceneState | None,
                 subsample: Subsample | None) -> np.ndarray:
    """(h, w, 3) uint8: the ``size`` picture drawn as a render job draws it: whole up to
    :data:`tessera.scheduling.render_jobs.WHOLE_SIDE` a side, larger window by window
    (:func:`tessera.scheduling.render_jobs.windows`), each cell of its window's framebuffer."""
    parts = windows(size)
    if len(parts) == 1:
        return renderer.render_frame(camera, size, state, subsample).pixels
    pixels = np.empty((size[1], size[0], 3), np.uint8)
    for cell, window in parts:
        drawn = renderer.render_tile(camera, size, cell, state=state, subsample=subsample, window=window).pixels
        pixels[cell.y:cell.y1, cell.x:cell.x1] = drawn
    return pixels


def _render_points(settings: NodeSettings, cloud: PointCloud, camera: Camera) -> int:
    """``--render-once`` of a point cloud (issue 36): the interactive frame within ``--point-budget``
    or the still the coordinator converges to, of every point in view (a cloud of more than
    :data:`tessera.points.budget.STILL_EVERY_POINT_MAX` points shows a still down to
    :data:`tessera.points.budget.STILL_SPACING_PX` first), splats of at least ``--point-size``,
    shaded by EDL."""
    assert settings.render_once is not None
    try:
        ctx = create_gl_context()
        renderer = PointRenderer(ctx, cloud, settings.background, settings.point_size)
        started = time.perf_counter()
        if settings.interactive:
            frame = renderer.render_frame(camera, settings.size, point_budget=settings.point_budget)
            pixels, drawn = frame.pixels, f"{frame.points} points drawn (budget {settings.point_budget})"
        else:
            points: list[int] = []
            renderer.style(settings.point_size, 0.0)

            def sample(subsample: Subsample | None) -> np.ndarray:
                frame = renderer.render_frame(camera, settings.size, subsample=subsample)
                points.append(frame.points)
                return frame.pixels

            still = accumulate_still(sample, settings.size, settings.still_plan)
            pixels, drawn = still.mean(), (f"{max(points)} points a sample (every point in view), {still.count} "
                                           f"jittered sample{'s' if still.count > 1 else ''}")
        render_ms = (time.perf_counter() - started) * 1e3
        settings.render_once.write_bytes(encode_png(pixels))
    except (SceneError, GLUnavailableError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except moderngl.Error as exc:
        print(f"error: GL failed: {' '.join(str(exc).split())}", file=sys.stderr)
        return 1
    except OSError as exc:
        print(f"error: cannot write {settings.render_once}: {exc.strerror or exc}", file=sys.stderr)
        return 1
    width, height = settings.size
    kind = "interactive frame" if settings.interactive else "still"
    print(f"wrote {settings.render_once} ({kind}, {width}x{height}, {cloud.point_count} points in {cloud.nodes.count} "
          f"octree nodes, {drawn}, render {render_ms:.1f} ms)")
    return 0


def _state(scene: SceneData, time: float, overrides: dict[str, ObjectPatch] | None, path: Path | None) -> SceneState:
    """``scene`` at ``time`` with ``overrides`` (read from ``path``); an unknown name lists the
    scene's objects."""
    try:
        return scene.state_at(time, overrides)
    except UnknownObjectError as exc:
        names = scene.objects.names
        listed = ", ".join(names[:20]) + (f", … ({len(names)} in all)" if len(names) > 20 else "")
        raise SceneStateError(f"objects file {path}: {exc}; the scene's objects are {listed}") from None
