"""GPU culling with temporal coherence (seed 001 §6.1.2), on llvmpipe: the GPU keeps exactly the
CPU's chunks, its commands draw exactly the tile's pixels, one command per batch a visible node
touches, and big trees are culled whole despite llvmpipe's shader loop limit. (The hybrid switch
in the renderer is tested in test_culled_rendering.py.)"""

from __future__ import annotations

import moderngl
import numpy as np
import pytest

from node.culling.bvh import build_chunk_bvh, cull, range_members
from node.culling.frustum import frustum_planes_from_matrix
from node.culling.gpu import MAX_SUBTREE_LEVELS, GpuBvh, GpuCuller
from node.culling.tiles import indirect_commands
from tessera.geometry import Camera, Rect, view_projection
from tests.culling_support import (
    classify_boxes,
    cull_flat,
    merge_ranges,
    read_commands,
    read_input_nodes,
    read_visible_chunks,
    split_bunny,
    tile_frustum_planes,
    tile_viewport,
)

pytestmark = pytest.mark.gl

SIZE = (1280, 720)
GRID_TILES = [Rect(x * 320, y * 180, 320, 180) for y in range(4) for x in range(4)]


@pytest.fixture(scope="module")
def bunny(ctx):
    """:func:`split_bunny` and its BVH on the GPU."""
    positions, faces, split, bvh, bounds = split_bunny()
    gpu_bvh = GpuBvh(ctx, bvh, split.starts * 3, split.ends * 3)
    yield positions, faces, split, bvh, bounds, gpu_bvh
    gpu_bvh.release()


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
            assert np.array_equal(read_visible_chunks(culler), expected), f"{camera} {rect}"
            assert_is_cut(bvh, read_input_nodes(culler))
            visible_total += expected.size
    for culler in cullers:
        culler.release()
    assert 0 < visible_total < 0.5 * len(path) * len(GRID_TILES) * bvh.chunk_count


def one_level_traversal_stops(bvh, planes: np.ndarray) -> np.ndarray:
    """(T,) sorted nodes where a one-level-at-a-time traversal from the root stops: culled, wholly
    inside every plane, or leaves, with no such node above them."""
    outside, inside = classify_boxes(bvh.lo, bvh.hi, planes)
    stop = outside.any(axis=1) | inside.all(axis=1) | bvh.is_leaf
    reached = np.zeros(bvh.node_count, bool)
    reached[0] = True
    for node in range(1, bvh.node_count):   # breadth-first order: parents first
        reached[node] = reached[bvh.parent[node]] and not stop[bvh.parent[node]]
    return np.flatnonzero(reached & stop)


def test_still_camera_input_settles_on_the_traversal_stops(bunny):
    _, _, _, bvh, bounds, gpu_bvh = bunny
    assert gpu_bvh.ceiling_depth == 0  # a small tree: inputs may climb to the root
    camera = orbit(bounds, 1, seed=4)[0]
    culler = GpuCuller(gpu_bvh)
    for rect in GRID_TILES[5], GRID_TILES[10]:
        planes = tile_frustum_planes(camera, SIZE, rect, bounds)
        expected = cull(bvh, planes)
        for _ in range(12):
            culler.cull(planes)
        assert np.array_equal(read_input_nodes(culler), one_level_traversal_stops(bvh, planes))
        culler.seed(expected.terminal_nodes)  # the seed's hand-over: the CPU's last nodes
        culler.cull(planes)
        assert np.array_equal(read_visible_chunks(culler), expected.visible_chunks)
    for not_a_cut in ([1], [0, 1], [1, 1, 2]):  # half the tree; nested nodes; a node twice
        with pytest.raises(ValueError):
            culler.seed(np.array(not_a_cut))
    culler.release()


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
        ranges = merge_ranges(result.visible_chunks, split.starts * 3, split.ends * 3)
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
    culler.release()
    assert drawn_tiles >= 4 and culled_tiles >= 4


def box_grid(count: int) -> np.ndarray:
    """(count, 2, 3) unit-spaced little boxes on a square grid in the z = 0 plane, row by row."""
    side = int(np.ceil(np.sqrt(count)))
    rows, cols = np.divmod(np.arange(count), side)
    centers = np.stack([cols, rows, np.zeros(count)], axis=1).astype(np.float64)
    return np.stack([centers - 0.3, centers + 0.3], axis=1)


def test_big_trees_are_culled_whole_despite_the_shader_loop_limit(ctx):
    """40 000 chunks cut by the near plane: every node is partly visible, so a traversal from the
    root would loop 80 000 times, and llvmpipe ends a shader loop after 32768 iterations."""
    boxes = box_grid(40_000)
    bvh = build_chunk_bvh(boxes)
    starts = np.arange(bvh.chunk_count) * 3
    gpu_bvh = GpuBvh(ctx, bvh, starts, starts + 3)
    assert gpu_bvh.ceiling_depth == int(bvh.depth.max()) - MAX_SUBTREE_LEVELS > 0
    bounds = np.array([[-1.0, -1.0, -1.0], [201.0, 201.0, 1.0]])
    size = (400, 300)
    slicing = Camera(eye=(100.0, 100.0, 260.0), target=(100.0, 100.0, 0.0), fovy_deg=60.0, near=260.0, far=900.0)
    plain = Camera(eye=(100.0, 100.0, 260.0), target=(100.0, 100.0, 0.0), fovy_deg=60.0)
    culler = GpuCuller(gpu_bvh)
    for camera, rect in ((slicing, Rect(0, 0, 400, 300)), (plain, Rect(20, 30, 200, 150)),
                         (plain, Rect(180, 130, 10, 10)), (slicing, Rect(0, 0, 400, 300))):
        planes = frustum_planes_from_matrix(view_projection(camera, size, bounds), size, rect)
        culler.cull(planes)
        expected = cull_flat(bvh, planes)
        assert expected.size > 0
        assert np.array_equal(read_visible_chunks(culler), expected), f"GPU lost chunks in {rect}"
        inputs = read_input_nodes(culler)
        assert_is_cut(bvh, inputs)
        assert bvh.depth[inputs].min() >= gpu_bvh.ceiling_depth or bvh.is_leaf[inputs].all()
    culler.release()
    gpu_bvh.release()


def test_a_visible_node_gets_one_command_per_batch(ctx):
    boxes = box_grid(64)
    bvh = build_chunk_bvh(boxes)
    batch_starts = np.array([0, 5, 6, 30, 64])                  # four batches of 5, 1, 24 and 34 chunks
    batch_end = np.repeat(batch_starts[1:], np.diff(batch_starts))
    starts = np.arange(65) * 6
    gpu_bvh = GpuBvh(ctx, bvh, starts[:-1], starts[1:], batch_end)
    culler = GpuCuller(gpu_bvh)
    camera = Camera(eye=(3.5, 3.5, 40.0), target=(3.5, 3.5, 0.0), fovy_deg=40.0)
    bounds = np.array([[-1.0, -1.0, -1.0], [8.0, 8.0, 1.0]])
    culler.cull(tile_frustum_planes(camera, (64, 64), Rect(0, 0, 64, 64), bounds))   # root wholly inside
    commands = read_commands(culler)
    heads = np.flatnonzero(commands[:, 0])
    assert heads.tolist() == batch_starts[:-1].tolist()
    assert commands[heads, 0].tolist() == (np.diff(batch_starts) * 6).tolist()
    assert commands[heads, 2].tolist() == (batch_starts[:-1] * 6).tolist()
    culler.release()
    gpu_bvh.release()
    with pytest.raises(ValueError):
        GpuBvh(ctx, bvh, starts[:-1], starts[1:], np.zeros(64, np.int64))
