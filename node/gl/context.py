"""The one GL context factory: a headless moderngl context on EGL.

EGL picks the NVIDIA driver when its vendor library is installed (``/usr/share/glvnd/egl_vendor.d``)
and Mesa's llvmpipe otherwise. This is the only place a GL context is created.

moderngl keeps the GIL inside every GL call, so while a frame is drawn no other thread of the
process runs Python: not the event loop, not a scene being read in the background. On llvmpipe a
draw takes the GIL twice for tens of milliseconds: the draw call, in which the calling thread
transforms and bins the vertices, and ``glFinish``, while llvmpipe's threads rasterise.
:func:`draw_indirect` and :func:`finish` make those calls through ctypes instead, which lets the
GIL go.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
from typing import Any

import moderngl

EGL_HELP = (
    "no usable EGL: install Debian's libegl1 and libegl-mesa0 (Mesa llvmpipe, CPU) or the NVIDIA "
    "driver's EGL library (libnvidia-egl / libnvidia-gl-*) for a GPU"
)


class GLUnavailableError(RuntimeError):
    """EGL or a GL 3.3 core context could not be created; the message says what to install."""


def create_gl_context() -> moderngl.Context:
    """A standalone GL ≥ 3.3 core context on EGL (no window, no display server)."""
    try:
        ctx = moderngl.create_standalone_context(backend="egl", require=330)
    except Exception as exc:
        raise GLUnavailableError(f"{EGL_HELP} ({exc})") from exc
    return ctx


def renderer_string(ctx: moderngl.Context) -> str:
    """Human-readable GL renderer, e.g. 'llvmpipe (LLVM 15.0.6, 256 bits)' or 'NVIDIA H100…'."""
    info = ctx.info
    return f"{info['GL_RENDERER']} | {info['GL_VENDOR']} | GL {info['GL_VERSION']}"


#: ``GL_DRAW_INDIRECT_BUFFER``, and the GL index types by the size of an index (bytes).
GL_DRAW_INDIRECT_BUFFER = 0x8F3F
GL_INDEX_TYPES = {1: 0x1401, 2: 0x1403, 4: 0x1405}
#: Bytes of one indirect draw command (five uint32, as moderngl's ``render_indirect`` reads them).
COMMAND_BYTES = 20
#: What :func:`draw_indirect` calls.
DRAW_PROCS = {"glUseProgram", "glBindVertexArray", "glBindBuffer", "glMultiDrawElementsIndirect",
              "glMultiDrawArraysIndirect"}


@functools.cache
def _gl_procs() -> dict[str, Any]:
    """The GL functions called through ctypes (which releases the GIL while they run), of the
    current context, by name, looked up with ``eglGetProcAddress``: those EGL gives."""
    try:
        egl = ctypes.CDLL(ctypes.util.find_library("EGL") or "libEGL.so.1")
        lookup = egl.eglGetProcAddress
    except (OSError, AttributeError):
        return {}
    lookup.restype, lookup.argtypes = ctypes.c_void_p, [ctypes.c_char_p]
    uint, size, int_ = ctypes.c_uint, ctypes.c_size_t, ctypes.c_int
    signatures = {"glFinish": (), "glUseProgram": (uint,), "glBindVertexArray": (uint,), "glBindBuffer": (uint, uint),
                  "glMultiDrawElementsIndirect": (uint, uint, size, int_, int_),
                  "glMultiDrawArraysIndirect": (uint, size, int_, int_)}
    return {name: ctypes.CFUNCTYPE(None, *argtypes)(address) for name, argtypes in signatures.items()
            if (address := lookup(name.encode()))}


def finish(ctx: moderngl.Context) -> None:
    """Wait until ``ctx`` (current on this thread, as moderngl keeps it) has done its GL work, as
    ``ctx.finish()`` does, but without holding the GIL meanwhile."""
    unlocked = _gl_procs().get("glFinish")
    if unlocked is None:
        ctx.finish()
    else:
        unlocked()


def draw_indirect(vertex_array: moderngl.VertexArray, commands: moderngl.Buffer, mode: int, count: int,
                  first: int = 0) -> None:
    """``vertex_array.render_indirect(commands, mode, count, first)`` (``count`` commands from
    command ``first``: glMultiDrawElementsIndirect, or Arrays without an index buffer) the way
    moderngl issues it, but without holding the GIL: llvmpipe transforms and bins the vertices in
    the calling thread (about 30 ms for 100k triangles over a 640x360 frame's 3x3 samples)."""
    procs = _gl_procs()
    if not procs.keys() >= DRAW_PROCS or vertex_array.scope is not None:
        vertex_array.render_indirect(commands, mode, count=count, first=first)
        return
    procs["glUseProgram"](vertex_array.program.glo)
    procs["glBindVertexArray"](vertex_array.glo)
    procs["glBindBuffer"](GL_DRAW_INDIRECT_BUFFER, commands.glo)
    if vertex_array.index_buffer is None:
        procs["glMultiDrawArraysIndirect"](mode, first * COMMAND_BYTES, count, COMMAND_BYTES)
    else:
        procs["glMultiDrawElementsIndirect"](mode, GL_INDEX_TYPES[vertex_array.index_element_size],
                                             first * COMMAND_BYTES, count, COMMAND_BYTES)
