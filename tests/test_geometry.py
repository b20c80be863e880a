"""Pure geometry: Rect, camera validation, the camera matrices and the tile viewport (no GL)."""

from __future__ import annotations

import itertools
import json
import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from tessera.geometry import (
    Camera,
    CameraError,
    Rect,
    default_camera,
    look_at,
    near_far_from_bounds,
    perspective,
    view_projection,
)
from tests.culling_support import tile_viewport

VALID = {"eye": [1.0, 2.0, 5.0], "target": [0.0, 0.5, 0.0], "up": [0.0, 1.0, 0.0], "fovy_deg": 50.0}
BOUNDS = np.array([[-1.0, -0.5, -2.0], [3.0, 1.5, 1.0]])
NAN, INF = float("nan"), float("inf")

coordinate = st.floats(-100.0, 100.0, allow_nan=False)
vector = st.tuples(coordinate, coordinate, coordinate)
unit_vector = st.tuples(*[st.floats(-1.0, 1.0)] * 3).filter(lambda v: math.hypot(*v) > 0.2)


def case_id(value: object) -> str:
    return json.dumps(value) if isinstance(value, dict) else str(value)


def camera_json(**changes: object) -> dict:
    return {**VALID, **changes}


def corners(bounds: np.ndarray) -> np.ndarray:
    """(8, 4) homogeneous corners of an axis-aligned box given as (2, 3)."""
    return np.array([[*corner, 1.0] for corner in itertools.product(*bounds.T)])


def to_ndc(matrix: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N, 3) normalised device coordinates of (N, 4) homogeneous points; asserts w > 0."""
    clip = points @ matrix.T
    assert (clip[:, 3] > 0).all(), "point behind the camera"
    return clip[:, :3] / clip[:, 3:]


# --------------------------------------------------------------------------------------------- Rect


def test_rect_properties_and_list_round_trip():
    rect = Rect(3, 4, 10, 20)
    assert (rect.area, rect.x1, rect.y1) == (200, 13, 24)
    assert Rect.from_seq(rect.as_list()) == rect


@pytest.mark.parametrize("values", [[1, 2, 3], [1, 2, 3, 4, 5], [0, 0, 1.0, 1], [0, 0, True, 1], ["0", 0, 1, 1]])
def test_rect_from_seq_rejects_anything_but_four_integers(values):
    with pytest.raises(ValueError, match="four integers"):
        Rect.from_seq(values)


@pytest.mark.parametrize(("other", "area"), [
    (Rect(0, 0, 10, 10), 100), (Rect(5, 5, 10, 10), 25), (Rect(10, 0, 5, 5), 0), (Rect(20, 20, 1, 1), 0),
])
def test_rect_intersection_area(other, area):
    assert Rect(0, 0, 10, 10).intersection_area(other) == area
    assert other.intersection_area(Rect(0, 0, 10, 10)) == area


# ---------------------------------------------------------------------------------- camera validation


@pytest.mark.parametrize(("changes", "fragment"), [
    ({"eye": [NAN, 0.0, 0.0]}, "eye"),
    ({"eye": [0.0, INF, 0.0]}, "eye"),
    ({"target": [0.0, 0.0, -INF]}, "target"),
    ({"target": [NAN, NAN, NAN]}, "target"),
    ({"up": [0.0, NAN, 0.0]}, "up"),
    ({"fovy_deg": NAN}, "fovy_deg"),
    ({"fovy_deg": INF}, "fovy_deg"),
    ({"near": NAN}, "near"),
    ({"far": INF}, "far"),
    ({"eye": [0.0, 0.5, 0.0]}, "coincide"),
    ({"up": [-1.0, -1.5, -5.0]}, "parallel"),
    ({"up": [2.0, 3.0, 10.0]}, "parallel"),
    ({"up": [0.0, 0.0, 0.0]}, "zero"),
    ({"fovy_deg": 0.0}, "fovy_deg"),
    ({"fovy_deg": 0.4}, "fovy_deg"),
    ({"fovy_deg": 179.5}, "fovy_deg"),
    ({"fovy_deg": -45.0}, "fovy_deg"),
    ({"near": 0.0}, "near"),
    ({"near": -1.0}, "near"),
    ({"near": 2.0, "far": 2.0}, "far"),
    ({"near": 2.0, "far": 1.0}, "far"),
    ({"far": -1.0}, "far"),
    ({"fov": 45.0}, "unknown"),
    ({"eye": {"x": 1, "y": 2, "z": 3}}, "eye"),
    ({"eye": "1,2,3"}, "eye"),
    ({"eye": 5.0}, "eye"),
    ({"eye": [1.0, 2.0]}, "eye"),
    ({"target": [1.0, 2.0, 3.0, 4.0]}, "target"),
    ({"up": None}, "up"),
    ({"eye": [1.0, None, 5.0]}, "eye"),
    ({"fovy_deg": [45]}, "fovy_deg"),
    ({"far": {}}, "far"),
], ids=case_id)
def test_from_json_rejects_bad_cameras_naming_the_problem(changes, fragment):
    with pytest.raises(CameraError, match=fragment):
        Camera.from_json(camera_json(**changes))


@pytest.mark.parametrize(("changes", "fragment"), [
    ({"eye": ["1", "2", "5"]}, "eye"),
    ({"target": [0.0, "0.5", 0.0]}, "target"),
    ({"fovy_deg": "45"}, "fovy_deg"),
    ({"near": "0.1"}, "near"),
    ({"eye": [True, 2.0, 5.0]}, "eye"),
    ({"fovy_deg": True}, "fovy_deg"),
    ({"far": False}, "far"),
], ids=case_id)
def test_from_json_rejects_strings_and_bools_where_numbers_belong(changes, fragment):
    with pytest.raises(CameraError, match=fragment):
        Camera.from_json(camera_json(**changes))


@pytest.mark.parametrize("missing", ["eye", "target"])
def test_from_json_requires_eye_and_target(missing):
    data = camera_json()
    del data[missing]
    with pytest.raises(CameraError, match=missing):
        Camera.from_json(data)


@pytest.mark.parametrize("data", [None, [1, 2, 3], "camera", 3.0])
def test_from_json_requires_an_object(data):
    with pytest.raises(CameraError, match="JSON object"):
        Camera.from_json(data)


@pytest.mark.parametrize("changes", [
    {"eye": (NAN, 2.0, 5.0)}, {"target": (0.0, INF, 0.0)}, {"up": (0.0, NAN, 0.0)}, {"fovy_deg": NAN},
    {"near": NAN}, {"far": NAN}, {"near": 0.1, "far": INF},
], ids=case_id)
def test_constructor_rejects_non_finite_values(changes):
    fields = {"eye": (1.0, 2.0, 5.0), "target": (0.0, 0.5, 0.0), **changes}
    with pytest.raises(CameraError):
        Camera(**fields)


def test_from_json_fills_defaults():
    camera = Camera.from_json({"eye": [0, 0, 5], "target": [0, 0, 0]})
    assert camera.up == (0.0, 1.0, 0.0)
    assert camera.fovy_deg == 45.0
    assert camera.near is None and camera.far is None
    assert "near" not in camera.to_json() and "far" not in camera.to_json()


@settings(max_examples=60, deadline=None)
@given(eye=vector, target=vector, up=unit_vector, fovy=st.floats(0.5, 179.0),
       near=st.none() | st.floats(1e-3, 10.0), far_extra=st.none() | st.floats(1e-3, 1e4))
def test_json_round_trip(eye, target, up, fovy, near, far_extra):
    far = None if far_extra is None else (near or 0.0) + far_extra
    try:
        camera = Camera(eye=eye, target=target, up=up, fovy_deg=fovy, near=near, far=far)
    except CameraError:
        assume(False)
    text = json.dumps(camera.to_json(), allow_nan=False)
    assert Camera.from_json(json.loads(text)) == camera


# ------------------------------------------------------------------------------------------ matrices


@settings(max_examples=60, deadline=None)
@given(eye=vector, target=vector, up=unit_vector)
def test_look_at_puts_eye_at_origin_and_target_on_minus_z(eye, target, up):
    try:
        Camera(eye=eye, target=target, up=up)
    except CameraError:
        assume(False)
    view = look_at(eye, target, up)
    distance = float(np.linalg.norm(np.subtract(target, eye)))
    np.testing.assert_allclose(view @ [*eye, 1.0], [0, 0, 0, 1], atol=1e-9 * max(distance, 100.0))
    np.testing.assert_allclose(view @ [*target, 1.0], [0, 0, -distance, 1], atol=1e-9 * max(distance, 100.0))
    rotation = view[:3, :3]
    np.testing.assert_allclose(rotation @ rotation.T, np.identity(3), atol=1e-9)
    assert np.linalg.det(rotation) == pytest.approx(1.0)
    assert (rotation @ np.asarray(up))[1] > 0.0, "world up should point up on screen"


@pytest.mark.parametrize(("fovy", "aspect", "near", "far"), [(45.0, 16 / 9, 0.1, 100.0), (90.0, 1.0, 2.0, 3.0),
                                                           (10.0, 0.5, 1e-3, 1e5)])
def test_perspective_maps_near_far_and_the_field_of_view_edges(fovy, aspect, near, far):
    proj = perspective(fovy, aspect, near, far)
    half_height = math.tan(math.radians(fovy) / 2.0)
    for depth, ndc_z in ((near, -1.0), (far, 1.0)):
        corner = [half_height * aspect * depth, half_height * depth, -depth, 1.0]
        ndc = to_ndc(proj, np.array([corner]))[0]
        np.testing.assert_allclose(ndc, [1.0, 1.0, ndc_z], rtol=1e-6, atol=1e-6)


@st.composite
def boxes(draw) -> np.ndarray:
    lo = np.array(draw(vector))
    extent = np.array(draw(st.tuples(*[st.floats(0.0, 50.0)] * 3)))
    assume(extent.max() > 1e-3)
    return np.stack([lo, lo + extent])


@st.composite
def cameras_outside(draw, bounds: np.ndarray) -> Camera:
    """A camera outside the box's bounding sphere, looking roughly at its centre."""
    center = bounds.mean(axis=0)
    radius = float(np.linalg.norm(bounds[1] - bounds[0])) / 2.0
    direction = np.array(draw(unit_vector))
    direction /= np.linalg.norm(direction)
    distance = radius * draw(st.floats(1.5, 20.0)) + 0.1
    jitter = np.array(draw(st.tuples(*[st.floats(-0.2, 0.2)] * 3))) * radius
    up = draw(unit_vector)
    try:
        return Camera(eye=tuple(center + direction * distance), target=tuple(center + jitter), up=up,
                      fovy_deg=draw(st.floats(10.0, 120.0)))
    except CameraError:
        assume(False)


@settings(max_examples=80, deadline=None)
@given(data=st.data(), bounds=boxes())
def test_near_far_from_bounds_encloses_every_corner(data, bounds):
    camera = data.draw(cameras_outside(bounds))
    near, far = near_far_from_bounds(camera, bounds)
    assert 0.0 < near < far
    depths = -(corners(bounds) @ look_at(camera.eye, camera.target, camera.up).T)[:, 2]
    assert depths.min() >= near and depths.max() <= far
    ndc_z = to_ndc(view_projection(camera, (640, 480), bounds), corners(bounds))[:, 2]
    assert ndc_z.min() >= -1.0 and ndc_z.max() <= 1.0


def test_near_far_from_bounds_honours_explicit_values():
    camera = Camera(eye=(0.0, 0.0, 50.0), target=(0.0, 0.0, 0.0), near=0.25, far=7.5)
    assert near_far_from_bounds(camera, BOUNDS) == (0.25, 7.5)


def test_an_explicit_near_alone_still_gives_a_far_beyond_it():
    camera = Camera(eye=(0.0, 0.0, 5.0), target=(0.0, 0.0, 0.0), near=100.0)
    near, far = near_far_from_bounds(camera, BOUNDS)
    assert near == 100.0
    assert far > near, f"derived far {far} is not beyond the explicit near {near}: depth would be inverted"


def test_an_explicit_far_alone_still_gives_a_near_before_it():
    camera = Camera(eye=(0.0, 0.0, 100.0), target=(0.0, 0.0, 0.0), far=1.0)
    near, far = near_far_from_bounds(camera, BOUNDS)
    assert far == 1.0
    assert 0.0 < near < far, f"derived near {near} is not before the explicit far {far}: depth would be inverted"


# ------------------------------------------------------------------------------------- tile viewport


def window_coords(ndc: np.ndarray, viewport: tuple[int, int, int, int]) -> np.ndarray:
    """GL viewport transform: (N, 2) window coordinates, y measured upwards from the bottom."""
    x0, y0, width, height = viewport
    return np.stack([x0 + (ndc[:, 0] + 1.0) / 2.0 * width, y0 + (ndc[:, 1] + 1.0) / 2.0 * height], axis=1)


@st.composite
def screens_and_rects(draw) -> tuple[tuple[int, int], Rect]:
    width, height = draw(st.integers(16, 4096)), draw(st.integers(16, 4096))
    x, y = draw(st.integers(0, width - 1)), draw(st.integers(0, height - 1))
    return (width, height), Rect(x, y, draw(st.integers(1, width - x)), draw(st.integers(1, height - y)))


@settings(max_examples=100, deadline=None)
@given(screen=screens_and_rects(), points=st.lists(st.tuples(*[st.floats(-1.0, 1.0)] * 3), min_size=1, max_size=8))
def test_tile_viewport_shifts_window_coordinates_by_the_rect_offset(screen, points):
    size, rect = screen
    camera = Camera(eye=(0.5, 1.0, 6.0), target=(0.0, 0.0, 0.0))
    matrix = view_projection(camera, size, np.array([[-1.0] * 3, [1.0] * 3]))
    ndc = to_ndc(matrix, np.array([[*p, 1.0] for p in points]))
    full = window_coords(ndc, (0, 0, *size))
    tile = window_coords(ndc, tile_viewport(rect, size))
    np.testing.assert_allclose(full[:, 0] - tile[:, 0], rect.x, atol=1e-6)
    np.testing.assert_allclose(full[:, 1] - tile[:, 1], size[1] - rect.y1, atol=1e-6)
    # In top-left pixel coordinates the tile's pixel is the full frame's pixel minus (x, y).
    full_rows, tile_rows = size[1] - full[:, 1], rect.h - tile[:, 1]
    np.testing.assert_allclose(tile_rows, full_rows - rect.y, atol=1e-6)


def test_tile_viewport_of_the_whole_screen_is_the_plain_viewport():
    assert tile_viewport(Rect(0, 0, 640, 480), (640, 480)) == (0, 0, 640, 480)


def test_tile_viewport_of_the_top_left_tile_moves_the_frame_down():
    # The top-left 100x50 tile shows the frame's top rows: the frame's bottom lies 430 px below it.
    assert tile_viewport(Rect(0, 0, 100, 50), (640, 480)) == (0, 50 - 480, 640, 480)


# ------------------------------------------------------------------------------------ default camera


@settings(max_examples=60, deadline=None)
@given(bounds=boxes(), size=st.sampled_from([(1280, 720), (1920, 1080), (1024, 1024), (800, 600), (3840, 1080)]),
       fovy=st.floats(20.0, 90.0))
def test_default_camera_sees_the_whole_box(bounds, size, fovy):
    camera = default_camera(bounds, fovy)
    ndc = to_ndc(view_projection(camera, size, bounds), corners(bounds))
    assert np.abs(ndc).max() <= 1.0
