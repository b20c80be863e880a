"""The GL calls :mod:`node.gl.context` makes through ctypes on real GL (llvmpipe): an indirect draw
draws what moderngl's ``render_indirect`` draws, and lets other Python threads run while it draws."""

from __future__ import annotations

import sys
import threading

import moderngl
import numpy as np
import pytest

from node.gl.context import draw_indirect, finish

pytestmark = pytest.mark.gl

SIZE = (512, 512)
VERTEX = """#version 330
in vec2 in_position;
void main() { gl_Position = vec4(in_position, 0.0, 1.0); }
"""
FRAGMENT = """#version 330
out vec4 colour;
void main() { colour = vec4(gl_FragCoord.x / 512.0, gl_FragCoord.y / 512.0, 0.5, 1.0); }
"""


@pytest.fixture(scope="module")
def grid_draw(ctx):
    """(vertex array over a grid of 2·n² triangles covering the lower left of the frame, its
    commands buffer: [the upper half of the grid's triangles, all of them], framebuffer)."""
    n = 600
    xs, ys = np.meshgrid(np.linspace(-1.0, 0.5, n + 1), np.linspace(-1.0, 0.5, n + 1))
    index = np.arange((n + 1) ** 2, dtype=np.uint32).reshape(n + 1, n + 1)
    a, b, c, d = index[:-1, :-1].ravel(), index[:-1, 1:].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([b, d, c], 1)]).astype(np.uint32)
    half = len(faces) // 2 * 3
    commands = np.array([[half, 1, half, 0, 0], [len(faces) * 3, 1, 0, 0, 0]], np.uint32)
    program = ctx.program(vertex_shader=VERTEX, fragment_shader=FRAGMENT)
    vertices = ctx.buffer(np.stack([xs.ravel(), ys.ravel()], 1).astype(np.float32).tobytes())
    indices, buffer = ctx.buffer(faces.tobytes()), ctx.buffer(commands.tobytes())
    vertex_array = ctx.vertex_array(program, [(vertices, "2f", "in_position")], indices, index_element_size=4)
    framebuffer = ctx.simple_framebuffer(SIZE)
    yield vertex_array, buffer, framebuffer
    for made in (framebuffer, vertex_array, buffer, indices, vertices, program):
        made.release()


def drawn(ctx, framebuffer, draw) -> np.ndarray:
    framebuffer.use()
    framebuffer.clear(0.0, 0.0, 0.0, 1.0)
    draw()
    finish(ctx)
    return np.frombuffer(framebuffer.read(components=3), np.uint8).reshape(SIZE[1], SIZE[0], 3)


@pytest.mark.parametrize("first,count", [(0, 1), (1, 1), (0, 2)])
def test_draw_indirect_draws_what_moderngl_draws(ctx, grid_draw, first, count):
    vertex_array, commands, framebuffer = grid_draw
    ours = drawn(ctx, framebuffer, lambda: draw_indirect(vertex_array, commands, moderngl.TRIANGLES, count, first))
    theirs = drawn(ctx, framebuffer, lambda: vertex_array.render_indirect(commands, moderngl.TRIANGLES, count=count,
                                                                          first=first))
    assert (ours != 0).any(axis=2).sum() > 0.1 * SIZE[0] * SIZE[1]   # something was drawn
    np.testing.assert_array_equal(ours, theirs)


def test_draw_indirect_lets_other_threads_run(ctx, grid_draw):
    """A thread woken just before a draw of 360k triangles runs during it. The main thread keeps the
    GIL unless it lets it go (the switch interval is made longer than the test), so the thread has
    run when the draw returns only if the draw let the GIL go."""
    vertex_array, commands, framebuffer = grid_draw
    framebuffer.use()
    gate, ran = threading.Lock(), []
    gate.acquire()

    def woken() -> None:
        with gate:
            ran.append(True)

    thread = threading.Thread(target=woken)
    thread.start()   # it waits on the gate
    interval = sys.getswitchinterval()
    sys.setswitchinterval(1000.0)
    try:
        gate.release()   # it takes the gate, then waits for the GIL
        draw_indirect(vertex_array, commands, moderngl.TRIANGLES, 1, 1)
        seen = list(ran)
    finally:
        sys.setswitchinterval(interval)
        thread.join()
        finish(ctx)
    assert seen == [True]
