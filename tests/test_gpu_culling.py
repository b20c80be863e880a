"""GPU culling with temporal coherence (seed 001 §6.1.2) and the hybrid culler (§6.2), on llvmpipe:
the GPU keeps exactly the CPU's chunks, its commands draw exactly the tile's pixels."""

from __future__ import annotations

from pathlib import Path

import moderngl
import numpy as np
import pytest
import trimesh

from node.culling_state import CullDevice, SwitchParams
from node.frustum_culling import (
    build_chunk_bvh,
    cull,
    indirect_commands,
    merge_ranges,
    range_members,
    tile_frustum_planes,
)
from node.gl_context import create_gl_context
from node.gpu_culling import GpuBvh, GpuCuller, HybridCuller
from node.octree_split import octree_split
from tessera.geometry import Camera, Rect, tile_viewport, view_projection

pytestmark = pytest.mark.gl

SCENES = Path(__file__).resolve().parents[1].parent / "shared" / "scenes"
SIZE = (1280, 720)
GRID_TILES = [Rect(x * 320, y * 180, 320, 180) for y in range(4) for x in range(4)]


@pytest.fixture(scope="module")
def ctx():
    context = create_gl_context()
    yield context
    context.release()


@pytest.fixture(scope="module")
def bunny(ctx):
    path = SCENES / "bunny" / "bun_zipper.ply"
    if not path.exists():
        pytest.fail(f"scene not found: the tests read real scenes from {SCENES}")
    mesh = trimesh.load(path, force="mesh")
    positions = np.asarray(mesh.vertices, dtype=np.float32)
    faces = np.asarray(mesh.faces, dtype=np.uint32)
    split = octree_split(positions, faces, face_limit=1024)
    bvh = build_chunk_bvh(split.bounds)
    bounds = np.array([positions.min(axis=0), positions.max(axis=0)], dtype=np.float64)
    gpu_bvh = GpuBvh(ctx, bvh, split.index_starts, split.index_ends)
    return positions, split.reorder(faces), split, bvh, bounds, gpu_bvh


def orbit(bounds: np.ndarray, frames: int, seed: int) -> list[Camera]:
    """A camera path: eye moving on a random arc around the model, distance and target drifting."""
    rng = np.random.default_rng(seed)
    center = bounds.mean(axis=0)
    radius = float(np.linalg.norm(bounds[1] - bounds[0])) / 2.0
    start, turn = rng.uniform(0, 2 * np.pi), rng.uniform(-0.6, 0.6)
    distance = rng.uniform(0.5, 2.5, size=2) * radius
    cameras = []
    for t in np.linspace(0.0, 1.0, frames):
        angle = start + turn * t
        eye = center + np.array([np.sin(angle), 0.3, np.cos(angle)]) * ((1 - t) * distance[0] + t * distance[1])
        target = center + np.array([0.2, -0.1, 0.0]) * radius * t
        cameras.append(Camera(eye=tuple(eye.tolist()), target=tuple(target.tolist()), fovy_deg=45.0))
    return cameras


def assert_is_cut(bvh, nodes: np.ndarray) -> None:
    covered = range_members(bvh.first_chunk[nodes], bvh.end_chunk[nodes])
    assert np.array_equal(np.sort(covered), np.arange(bvh.chunk_count)), "input nodes are not a cut of the tree"


def test_gpu_keeps_the_same_chunks_as_the_cpu_along_camera_paths(bunny):
    _, _, _, bvh, bounds, gpu_bvh = bunny
    cullers = [GpuCuller(gpu_bvh) for _ in GRID_TILES]
    jumps = [Camera(eye=(0.0, 0.1, 0.02), target=(0.0, 0.1, -1.0)), Camera(eye=(0.5, 0.5, 0.5), target=(0.0, 0.1, 0.0))]
    path = orbit(bounds, 10, seed=1) + jumps + orbit(bounds, 10, seed=2)
    visible_total = 0
    for camera in path:
        for rect, culler in zip(GRID_TILES, cullers, strict=True):
            planes = tile_frustum_planes(camera, SIZE, rect, bounds)
            culler.cull(planes)
            expected = cull(bvh, planes).visible_chunks
            assert np.array_equal(culler.read_visible_chunks(), expected), f"{camera} {rect}"
            assert_is_cut(bvh, culler.read_input_nodes())
            visible_total += expected.size
    assert 0 < visible_total < 0.5 * len(path) * len(GRID_TILES) * bvh.chunk_count


def test_still_camera_input_settles_on_the_cpu_terminal_nodes(bunny):
    _, _, _, bvh, bounds, gpu_bvh = bunny
    camera = orbit(bounds, 1, seed=4)[0]
    culler = GpuCuller(gpu_bvh)
    for rect in GRID_TILES[5], GRID_TILES[10]:
        planes = tile_frustum_planes(camera, SIZE, rect, bounds)
        expected = cull(bvh, planes)
        for _ in range(12):
            culler.cull(planes)
        assert np.array_equal(culler.read_input_nodes(), np.sort(expected.terminal_nodes))
        culler.seed(expected.terminal_nodes)  # the seed's hand-over: the CPU's last nodes
        culler.cull(planes)
        assert np.array_equal(culler.read_visible_chunks(), expected.visible_chunks)
    for not_a_cut in ([1], [0, 1], [1, 1, 2]):  # half the tree; nested nodes; a node twice
        with pytest.raises(ValueError):
            culler.seed(np.array(not_a_cut))


@pytest.fixture(scope="module")
def bunny_vao(ctx, bunny):
    """The split bunny as one vertex array; colour = position, so every pixel says what it shows."""
    positions, faces = bunny[0], bunny[1]
    program = ctx.program(
        vertex_shader="""#version 330
            uniform mat4 mvp; in vec3 in_position; out vec3 color;
            void main() { gl_Position = mvp * vec4(in_position, 1.0); color = in_position * 4.0 + 0.5; }""",
        fragment_shader="""#version 330
            in vec3 color; out vec4 frag; void main() { frag = vec4(color, 1.0); }""")
    vbo, ibo = ctx.buffer(positions.tobytes()), ctx.buffer(faces.astype(np.uint32).tobytes())
    vao = ctx.vertex_array(program, [(vbo, "3f", "in_position")], index_buffer=ibo, index_element_size=4)
    yield vao
    for resource in (vao, vbo, ibo, program):
        resource.release()


def render_tile(ctx, vao, view_proj, size, rect, draw) -> np.ndarray:
    """Render ``rect`` of a ``size`` frame with ``draw(vao)``: (h, w, 3) uint8."""
    vao.program["mvp"].write(view_proj.T.astype(np.float32).tobytes())
    fbo = ctx.framebuffer(color_attachments=[ctx.renderbuffer((rect.w, rect.h))],
                          depth_attachment=ctx.depth_renderbuffer((rect.w, rect.h)))
    fbo.use()
    ctx.viewport = tile_viewport(rect, size)
    fbo.clear(0.0, 0.0, 0.0, 1.0, depth=1.0)
    ctx.enable(moderngl.DEPTH_TEST)
    draw(vao)
    pixels = np.frombuffer(fbo.read(components=3), np.uint8).reshape(rect.h, rect.w, 3).copy()
    fbo.release()
    return pixels


def test_indirect_commands_draw_exactly_the_tile_pixels(ctx, bunny, bunny_vao):
    _, _, split, bvh, bounds, gpu_bvh = bunny
    size = (128, 96)
    camera = Camera(eye=(0.05, 0.2, 0.12), target=(-0.02, 0.1, 0.0), fovy_deg=50.0)
    view_proj = view_projection(camera, size, bounds)
    culler = GpuCuller(gpu_bvh)
    drawn_tiles = culled_tiles = 0
    for rect in [Rect(x * 32, y * 24, 32, 24) for y in range(4) for x in range(4)]:
        planes = tile_frustum_planes(camera, size, rect, bounds)
        result = cull(bvh, planes)
        ranges = merge_ranges(result.visible_chunks, split.index_starts, split.index_ends)
        cpu_commands = ctx.buffer(indirect_commands(ranges).tobytes() or b"\0" * 20)
        culler.cull(planes)

        def draw_all(vao):
            vao.render(moderngl.TRIANGLES)

        def draw_ranges(vao, ranges=ranges):
            for start, count in ranges:
                vao.render(moderngl.TRIANGLES, vertices=count, first=start)

        def draw_cpu_indirect(vao, buffer=cpu_commands, count=len(ranges)):
            if count:
                vao.render_indirect(buffer, moderngl.TRIANGLES, count=count)

        def draw_gpu_indirect(vao):
            vao.render_indirect(culler.commands, moderngl.TRIANGLES, count=culler.command_count)

        images = [render_tile(ctx, bunny_vao, view_proj, size, rect, draw)
                  for draw in (draw_all, draw_ranges, draw_cpu_indirect, draw_gpu_indirect)]
        cpu_commands.release()
        for image in images[1:]:
            assert np.array_equal(image, images[0]), f"culled draw differs from the full draw in {rect}"
        drawn_tiles += int(images[0].any(axis=2).any())
        assert len(ranges) <= result.visible_chunks.size
        culled_tiles += int(result.visible_chunks.size < split.chunk_count)
    assert drawn_tiles >= 4 and culled_tiles >= 4


def test_hybrid_culler_switches_to_the_gpu_and_back(bunny):
    _, _, split, bvh, bounds, gpu_bvh = bunny
    always_slow = SwitchParams(threshold_s=1e-12, frames_to_switch=3, gpu_frames=4, check_frames=2)
    hybrid = HybridCuller(gpu_bvh, always_slow)
    devices = []
    for camera in orbit(bounds, 10, seed=3):
        planes = tile_frustum_planes(camera, SIZE, GRID_TILES[6], bounds)
        draw = hybrid.cull("tile-6", planes)
        devices.append(draw.device)
        expected = cull(bvh, planes).visible_chunks
        commands = np.frombuffer(draw.indirect.read(), np.uint32).reshape(-1, 5)[:draw.command_count]
        drawn = commands[commands[:, 0] > 0]
        chunks = range_members(np.searchsorted(split.index_starts, drawn[:, 2]),
                               np.searchsorted(split.index_starts, drawn[:, 2].astype(np.int64) + drawn[:, 0]))
        assert np.array_equal(np.sort(chunks), expected)
        if draw.device is CullDevice.CPU:
            assert draw.ranges == merge_ranges(expected, split.index_starts, split.index_ends)
    cpu, gpu = CullDevice.CPU, CullDevice.GPU
    assert devices == [cpu] * 3 + [gpu] * 4 + [cpu] + [gpu] * 2
