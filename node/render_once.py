"""``python -m node --render-once OUT.png``: one full frame rendered alone, no coordinator — the
reference image every composited frame is checked against. ``--face-limit`` and ``--culling`` apply
as on a serving node; neither changes the image."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import moderngl

from node.culling.tiles import CullingUnavailableError
from node.gl.context import GLUnavailableError, create_gl_context
from node.gl.renderer import TileRenderer
from node.scene.loading import load_scene
from node.scene.mesh import SceneError
from node.settings import NodeSettings
from tessera.codec import encode_png
from tessera.geometry import Camera, CameraError, default_camera


def read_camera(path: Path) -> Camera:
    """Parse a camera JSON file; raises CameraError whose message names the file and the reason."""
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise CameraError(f"camera file {path}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise CameraError(f"camera file {path}: unreadable ({exc})") from None
    except ValueError as exc:
        raise CameraError(f"camera file {path}: invalid JSON ({exc})") from None
    try:
        return Camera.from_json(data)
    except CameraError as exc:
        raise CameraError(f"camera file {path}: {exc}") from None


def render_once(settings: NodeSettings) -> int:
    """Render ``settings.scene`` to ``settings.render_once`` (PNG); returns the exit code and
    prints one ``error: …`` line on failure."""
    assert settings.render_once is not None
    try:
        camera = read_camera(settings.camera) if settings.camera is not None else None
        scene = load_scene(settings.scene, face_limit=settings.face_limit)
        camera = camera or default_camera(scene.bounds)
        ctx = create_gl_context()
        renderer = TileRenderer(ctx, scene, settings.background, culling=settings.culling)
        frame = renderer.render_frame(camera, settings.size)
        settings.render_once.write_bytes(encode_png(frame.pixels))
    except (CameraError, SceneError, GLUnavailableError, CullingUnavailableError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except moderngl.Error as exc:
        print(f"error: GL failed: {' '.join(str(exc).split())}", file=sys.stderr)
        return 1
    except OSError as exc:
        print(f"error: cannot write {settings.render_once}: {exc.strerror or exc}", file=sys.stderr)
        return 1
    width, height = settings.size
    print(f"wrote {settings.render_once} ({width}x{height}, {scene.triangle_count} triangles in "
          f"{scene.chunks.chunk_count} chunks, {frame.triangles} drawn, {frame.cull_path} culling, "
          f"render {frame.render_ms:.1f} ms)")
    return 0
