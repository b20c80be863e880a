"""Generated scenes (``builtin:NAME``), deterministic and fast to build (numpy only, no trimesh).

``cluster`` is the coordinator's default: its screen load is deliberately uneven — a dense cluster
of detailed objects (spheres, tori, capsules, ~250 k triangles) on one side of a wide, sparse
ground — so that equal tiles are badly balanced and load balancing visibly matters (seed 000 §4).
``spheres`` is a small scene (~4 k triangles) for fast tests.

``traffic`` is the dynamic one (issue 11): cars of uneven detail drive along four lanes across a
road at different speeds, wrapping round at the lane ends, and a sign turns above the middle, so
the screen load moves with them (~90 k triangles). The motion is a glTF-style animation
(:mod:`tessera.scene.animation`: LINEAR translation and rotation keyframes), so the scene at time t is
deterministic and sampled like a file's; it loops seamlessly every :data:`TRAFFIC_LOOP_S` seconds
(every lane's period divides it). A car's wrap is two keyframes at the same time, the lane's end
and its start: the sampler jumps there instead of sliding the car back across the road.
"""

from __future__ import annotations

import colorsys
import dataclasses
from collections.abc import Callable

import numpy as np

from node.scene.data import SceneData
from node.scene.mesh import MeshBatch, SceneError
from tessera.scene.animation import Animation, Channel, Sampler
from tessera.scene.graph import SceneObject
from tessera.scene.state import ObjectState, matrix_quaternion

#: ``(positions (N, 3), normals (N, 3), faces (F, 3))`` of an object in its local frame.
Surface = tuple[np.ndarray, np.ndarray, np.ndarray]

CLUSTER_SEED = 20240917
CLUSTER_OBJECTS = 48
#: Centre of the dense cluster on the ground plane (x, z) and the ground's half extent.
CLUSTER_CENTER = (-2.6, -0.5)
GROUND_HALF = 5.0
#: Traffic: lane half length (x from −L to L), and (z, direction, period s, cars, detail, size) per lane.
TRAFFIC_HALF = 8.0
TRAFFIC_LANES = ((-3.0, 1, 8.0, 3, 48, 1.0), (-1.0, -1, 16.0, 3, 24, 0.9), (1.0, 1, 10.0, 3, 32, 1.0),
                 (3.0, -1, 20.0, 2, 64, 1.6))
#: The traffic animation's length: a multiple of every lane's period and of the sign's turn.
TRAFFIC_LOOP_S = 80.0
TRAFFIC_SIGN_TURN_S = 8.0


def grid_faces(rows: int, cols: int) -> np.ndarray:
    """Triangles (2·rows·cols, 3) uint32 of a (rows+1)×(cols+1) vertex grid, row-major."""
    r, c = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    a = (r * (cols + 1) + c).reshape(-1)
    b, d = a + 1, a + cols + 1
    quads = np.stack([a, d, b, b, d, d + 1], axis=1).reshape(-1, 3)
    return quads.astype(np.uint32)


def sphere(rows: int, cols: int, stretch: float = 0.0) -> Surface:
    """Unit latitude–longitude sphere; ``stretch`` > 0 pulls the hemispheres apart by that much
    along y (a capsule, with a cylinder between the two duplicated equator rings)."""
    half = rows // 2
    latitudes = np.concatenate([np.linspace(-np.pi / 2, 0.0, half + 1), np.linspace(0.0, np.pi / 2, half + 1)])
    longitudes = np.linspace(0.0, 2.0 * np.pi, cols + 1)
    lat, lon = np.meshgrid(latitudes, longitudes, indexing="ij")
    normals = np.stack([np.cos(lat) * np.cos(lon), np.sin(lat), -np.cos(lat) * np.sin(lon)], axis=-1).reshape(-1, 3)
    positions = normals.copy()
    offsets = np.where(np.arange(len(latitudes)) > half, stretch / 2.0, -stretch / 2.0)
    positions[:, 1] += np.repeat(offsets, cols + 1)
    return positions, normals, grid_faces(2 * half + 1, cols)


def torus(rows: int, cols: int, minor: float = 0.35) -> Surface:
    """Torus of major radius 1 around y, tube radius ``minor``."""
    tube, ring = np.meshgrid(np.linspace(0.0, 2.0 * np.pi, rows + 1), np.linspace(0.0, 2.0 * np.pi, cols + 1),
                             indexing="ij")
    normals = np.stack([np.cos(tube) * np.cos(ring), np.sin(tube), -np.cos(tube) * np.sin(ring)], axis=-1)
    centres = np.stack([np.cos(ring), np.zeros_like(ring), -np.sin(ring)], axis=-1)
    positions = centres + minor * normals
    return positions.reshape(-1, 3), normals.reshape(-1, 3), grid_faces(rows, cols)


def ground(half: float, cells: int) -> Surface:
    """Flat square on y = 0 from −half to +half in x and z, ``cells``² quads, normal +y."""
    ticks = np.linspace(-half, half, cells + 1)
    z, x = np.meshgrid(ticks, ticks, indexing="ij")
    positions = np.stack([x, np.zeros_like(x), z], axis=-1).reshape(-1, 3)
    normals = np.tile([0.0, 1.0, 0.0], (len(positions), 1))
    return positions, normals, grid_faces(cells, cells)


def rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """3×3 rotation about unit ``axis`` by ``angle`` radians (Rodrigues)."""
    x, y, z = axis / np.linalg.norm(axis)
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.identity(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * (k @ k)


def place(name: str, surface: Surface, scale: np.ndarray, turn: np.ndarray, offset: np.ndarray,
          color: tuple[float, float, float]) -> MeshBatch:
    """A batch of ``surface`` scaled per axis, rotated by ``turn`` (3×3), moved by ``offset``."""
    positions, normals, faces = surface
    linear = turn @ np.diag(scale)
    world_normals = normals @ np.linalg.inv(linear)
    world_normals /= np.linalg.norm(world_normals, axis=1, keepdims=True)
    return MeshBatch(
        name=name,
        positions=(positions @ linear.T + offset).astype(np.float32),
        normals=world_normals.astype(np.float32),
        faces=faces,
        base_color=np.asarray([*color, 1.0], dtype=np.float32),
    )


def _ground_batch(half: float, cells: int) -> MeshBatch:
    return place("ground", ground(half, cells), np.ones(3), np.identity(3), np.zeros(3), (0.16, 0.18, 0.17))


def cluster_scene() -> SceneData:
    """Dense detailed cluster left of centre, a few low-poly markers on the right, wide ground."""
    rng = np.random.default_rng(CLUSTER_SEED)
    batches = [_ground_batch(GROUND_HALF, 4)]
    kinds = ("sphere", "torus", "capsule")
    for number in range(CLUSTER_OBJECTS):
        kind = kinds[number % 3]
        detail = int(rng.choice([24, 32, 48]))
        size = rng.uniform(0.3, 0.65)
        if kind == "sphere":
            surface, scale = sphere(detail, 2 * detail), np.full(3, size)
        elif kind == "torus":
            surface, scale = torus(detail, 2 * detail, minor=rng.uniform(0.25, 0.45)), np.full(3, size)
        else:
            surface, scale = sphere(detail, 2 * detail, stretch=rng.uniform(1.0, 2.5)), np.full(3, size * 0.6)
        x, z = rng.normal(CLUSTER_CENTER, (1.1, 1.0))
        offset = np.array([x, size + rng.uniform(0.0, 2.2), z])
        turn = rotation(rng.normal(size=3), rng.uniform(0.0, np.pi))
        color = colorsys.hsv_to_rgb(rng.uniform(0.0, 1.0), rng.uniform(0.5, 0.8), 0.75)
        batches.append(place(f"{kind}{number}", surface, scale, turn, offset, color))
    for number in range(5):
        marker = sphere(2, 4, stretch=0.6)
        offset = np.array([1.2 + 0.8 * number, 0.5, rng.uniform(-3.0, 3.0)])
        batches.append(place(f"marker{number}", marker, np.array([0.6, 0.5, 0.6]),
                             rotation(np.array([0.0, 1.0, 0.0]), rng.uniform(0.0, np.pi)), offset, (0.55, 0.5, 0.42)))
    return SceneData.from_batches("builtin:cluster", batches)


def spheres_scene() -> SceneData:
    """Four small spheres on a ground square, ~4 k triangles."""
    batches = [_ground_batch(2.0, 2)]
    colors = [(0.8, 0.2, 0.15), (0.2, 0.6, 0.25), (0.2, 0.35, 0.8), (0.85, 0.7, 0.2)]
    for number, color in enumerate(colors):
        offset = np.array([-1.2 + 0.8 * number, 0.35 + 0.15 * number, 0.3 * (number % 2)])
        batches.append(place(f"sphere{number}", sphere(16, 32), np.full(3, 0.35), np.identity(3), offset, color))
    return SceneData.from_batches("builtin:spheres", batches)


def traffic_scene() -> SceneData:
    """Cars on four lanes and a turning sign, animated (see the module docstring)."""
    length = 2.0 * TRAFFIC_HALF
    batches = [place("road", ground(TRAFFIC_HALF, 8), np.array([1.0, 1.0, 0.55]), np.identity(3), np.zeros(3),
                     (0.2, 0.2, 0.22))]
    objects = [SceneObject("road")]
    channels = []
    for lane, (z, direction, period, cars, detail, size) in enumerate(TRAFFIC_LANES):
        turn = rotation(np.array([0.0, 0.0, 1.0]), np.pi / 2)            # the capsule's long axis along x
        if direction < 0:
            turn = rotation(np.array([0.0, 1.0, 0.0]), np.pi) @ turn
        color = colorsys.hsv_to_rgb(0.08 + 0.22 * lane, 0.7, 0.8)
        for number in range(cars):
            name = f"car{lane}_{number}"
            start = _wrap((number + 0.5 + 0.3 * lane) * length / cars - TRAFFIC_HALF)
            offset = np.array([start, 0.35 * size, z])
            batches.append(dataclasses.replace(
                place(name, sphere(detail, 2 * detail, stretch=2.0), np.full(3, 0.3 * size), turn, offset, color),
                owner=len(objects)))
            objects.append(SceneObject(name, base=ObjectState(tuple(offset.tolist()), matrix_quaternion(turn))))
            channels.append(Channel(name, "translation", _lane_sampler(offset, direction * length / period)))
    sign_height = 2.4
    batches.append(dataclasses.replace(
        place("sign", torus(48, 96), np.full(3, 0.6), rotation(np.array([1.0, 0.0, 0.0]), np.pi / 2),
              np.array([0.0, sign_height, 0.0]), (0.85, 0.75, 0.2)), owner=len(objects)))
    objects.append(SceneObject("sign", base=ObjectState((0.0, sign_height, 0.0))))
    channels.append(Channel("sign", "rotation", _turn_sampler()))
    return SceneData.from_batches("builtin:traffic", batches, objects=objects,
                                  animations=[Animation("traffic", tuple(channels))])


def _wrap(x: float) -> float:
    """``x`` wrapped into the lane, [−L, L)."""
    return (x + TRAFFIC_HALF) % (2.0 * TRAFFIC_HALF) - TRAFFIC_HALF


def _lane_sampler(start: np.ndarray, speed: float) -> Sampler:
    """LINEAR translation keyframes (K, 3) over [0, TRAFFIC_LOOP_S] of a car leaving ``start`` at
    ``speed`` (units/s along x, signed), a pair of keyframes at each wrap (the lane's end, then its
    other end)."""
    end, begin = (TRAFFIC_HALF, -TRAFFIC_HALF) if speed > 0 else (-TRAFFIC_HALF, TRAFFIC_HALF)
    period = 2.0 * TRAFFIC_HALF / abs(speed)
    times, xs = [0.0], [float(start[0])]
    wrap = (end - start[0]) / speed
    while wrap < TRAFFIC_LOOP_S:
        times += [wrap, wrap]
        xs += [end, begin]
        wrap += period
    times.append(TRAFFIC_LOOP_S)
    xs.append(float(start[0]))          # the loop is a whole number of periods: back at the start
    values = np.tile(start, (len(xs), 1))
    values[:, 0] = xs
    return Sampler(np.array(times), values, "LINEAR")


def _turn_sampler() -> Sampler:
    """LINEAR rotation keyframes about y, an eighth of a turn apart (slerp turns at a steady rate),
    a full turn every TRAFFIC_SIGN_TURN_S seconds."""
    steps = round(8 * TRAFFIC_LOOP_S / TRAFFIC_SIGN_TURN_S)
    times = np.linspace(0.0, TRAFFIC_LOOP_S, steps + 1)
    half_angles = (np.arange(steps + 1) % 16) * (np.pi / 8)     # a quaternion repeats every two turns
    values = np.stack([np.zeros_like(times), np.sin(half_angles), np.zeros_like(times), np.cos(half_angles)], axis=1)
    return Sampler(times, values, "LINEAR", rotation=True)


_BUILDERS: dict[str, Callable[[], SceneData]] = {"cluster": cluster_scene, "spheres": spheres_scene,
                                                 "traffic": traffic_scene}
BUILTIN_SCENES: tuple[str, ...] = tuple(_BUILDERS)


def build_builtin_scene(name: str) -> SceneData:
    """The generated scene ``name`` (one of :data:`BUILTIN_SCENES`)."""
    builder = _BUILDERS.get(name)
    if builder is None:
        raise SceneError(f"builtin:{name}: unknown built-in scene; choose one of {', '.join(BUILTIN_SCENES)}")
    return builder()
