"""Picking on real GL (llvmpipe, issue 35): the id pass of one pixel finds the object the pixel's
centre sees, and the world point within half a pixel's footprint of the truth, on geometry whose
position is known (the flat ground of ``builtin:spheres`` at y = 0, its spheres' centres); moved
and hidden objects, clip planes and their caps, sort-last shares."""

from __future__ import annotations

import math

import numpy as np
import pytest

from node.gl.renderer import TileRenderer
from node.gl.view_tools import ViewTools
from node.scene.builtin import build_builtin_scene
from node.scene.shares import keep_share
from tessera.geometry import Camera, view_projection
from tessera.scene.state import ObjectPatch
from tessera.tools.clipping import ClipState
from tessera.tools.picking import nearest, pixel_ray

pytestmark = pytest.mark.gl

SIZE = (1280, 720)
CAMERA = Camera(eye=(0.3, 2.4, 4.2), target=(0.0, 0.2, 0.0), fovy_deg=45.0)


@pytest.fixture(scope="module")
def scene():
    return build_builtin_scene("spheres")


@pytest.fixture(scope="module")
def renderer(ctx, scene):
    made = TileRenderer(ctx, scene)
    yield made
    made.release()


def project(point, camera: Camera, bounds) -> tuple[int, int]:
    clip = view_projection(camera, SIZE, bounds) @ np.append(np.asarray(point, dtype=float), 1.0)
    ndc = clip[:3] / clip[3]
    return int((ndc[0] + 1) / 2 * SIZE[0]), int((1 - ndc[1]) / 2 * SIZE[1])


def footprint(depth: float, camera: Camera) -> float:
    """The width of one pixel at ``depth`` along the view (scene units)."""
    return depth * 2.0 * math.tan(math.radians(camera.fovy_deg) / 2.0) / SIZE[1]


def sphere_centre(scene, name: str) -> np.ndarray:
    lo, hi = scene.objects.objects[scene.objects.lookup(name)].bounds
    return (lo + hi) / 2.0


def test_ground_points_lie_within_half_a_pixel_of_the_truth(renderer, scene) -> None:
    rng = np.random.default_rng(35)
    checked = 0
    for _ in range(40):
        x, y = int(rng.integers(0, SIZE[0])), int(rng.integers(SIZE[1] // 2, SIZE[1]))
        hit = renderer.pick(CAMERA, SIZE, x, y)
        if hit is None or hit.object != "ground":
            continue
        origin, direction = pixel_ray(CAMERA, SIZE, scene.bounds, x, y)
        truth = origin + direction * (-origin[1] / direction[1])   # the ray meets y = 0
        assert abs(truth[0]) <= 2.0 and abs(truth[2]) <= 2.0
        error = float(np.linalg.norm(np.asarray(hit.point) - truth))
        assert error <= 0.5 * footprint(hit.depth, CAMERA), (x, y, error)
        assert np.allclose(hit.normal, (0.0, 1.0, 0.0)) and math.isclose(hit.depth, np.linalg.norm(truth - origin))
        checked += 1
    assert checked >= 10


def test_spheres_are_named_and_hit_on_their_surface(renderer, scene) -> None:
    for number in range(4):
        name = f"sphere{number}"
        centre = sphere_centre(scene, name)
        hit = renderer.pick(CAMERA, SIZE, *project(centre, CAMERA, scene.bounds))
        assert hit is not None and hit.object == name
        assert abs(np.linalg.norm(np.asarray(hit.point) - centre) - 0.35) < 0.01
        towards_eye = np.asarray(CAMERA.eye) - np.asarray(hit.point)
        assert np.dot(hit.normal, towards_eye) > 0.0
        assert 0 <= hit.primitive < scene.objects.objects[scene.objects.lookup(name)].triangles
    assert renderer.pick(CAMERA, SIZE, 5, 5) is None, "the sky is background"


def test_moved_and_hidden_objects_are_picked_where_they_are(renderer, scene) -> None:
    centre = sphere_centre(scene, "sphere1")
    state = scene.state_at(0.0, {"sphere1": ObjectPatch(translation=(0.0, 1.0, 0.0)),
                                 "sphere2": ObjectPatch(visible=False)})
    bounds = renderer.pose_of(state).bounds
    moved = renderer.pick(CAMERA, SIZE, *project(centre + np.array([0.0, 1.0, 0.0]), CAMERA, bounds), state)
    assert moved is not None and moved.object == "sphere1"
    gone = renderer.pick(CAMERA, SIZE, *project(sphere_centre(scene, "sphere2"), CAMERA, bounds), state)
    assert gone is None or gone.object != "sphere2"


def test_a_cut_is_picked_on_its_plane(renderer, scene) -> None:
    centre = sphere_centre(scene, "sphere3")
    towards_eye = np.asarray(CAMERA.eye) - centre
    towards_eye /= np.linalg.norm(towards_eye)
    # keep what lies behind the plane through the centre: the pixel at the centre sees the cap
    clip = ClipState.from_json({"planes": [{"point": centre.tolist(), "normal": (-towards_eye).tolist()}]})
    renderer.use_tools(ViewTools(clip))
    try:
        pixel = project(centre, CAMERA, scene.bounds)
        hit = renderer.pick(CAMERA, SIZE, *pixel)
        assert hit is not None and hit.object == "sphere3"
        assert abs(float(np.dot(np.asarray(hit.point) - centre, towards_eye))) < 1e-6, "on the cutting plane"
        assert np.allclose(hit.normal, towards_eye)
        renderer.use_tools(ViewTools(ClipState.from_json({**clip.to_json(), "cap": False})))
        inside = renderer.pick(CAMERA, SIZE, *pixel)
        assert inside is not None and np.dot(np.asarray(inside.point) - centre, towards_eye) < -0.3, \
            "without a cap the pixel sees the far inside of the sphere"
        renderer.use_tools(ViewTools(ClipState.from_json({"box": {"min": [5, 5, 5], "max": [6, 6, 6]}})))
        assert renderer.pick(CAMERA, SIZE, *pixel) is None
    finally:
        renderer.use_tools(None)


def test_sort_last_shares_answer_the_nearest(ctx, scene, renderer) -> None:
    weights = (1.0, 1.0, 1.0)
    shares = [TileRenderer(ctx, keep_share(scene, weights, index)) for index in range(len(weights))]
    try:
        rng = np.random.default_rng(7)
        for _ in range(12):
            x, y = int(rng.integers(200, 1080)), int(rng.integers(200, 700))
            whole = renderer.pick(CAMERA, SIZE, x, y)
            merged = nearest(share.pick(CAMERA, SIZE, x, y) for share in shares)
            assert (whole is None) == (merged is None)
            if whole is not None and merged is not None:
                assert merged.object == whole.object and np.allclose(merged.point, whole.point)
    finally:
        for share in shares:
            share.release()
