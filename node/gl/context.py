"""The one GL context factory: a headless moderngl context on EGL.

EGL picks the NVIDIA driver when its vendor library is installed (``/usr/share/glvnd/egl_vendor.d``)
and Mesa's llvmpipe otherwise. This is the only place a GL context is created.

moderngl keeps the GIL inside every GL call, so while a frame is drawn (llvmpipe's threads
rasterise it while the calling thread waits in ``glFinish``: tens of milliseconds) no other thread
of the process runs Python: not the event loop, not a scene being read in the background.
:func:`finish` waits in ``glFinish`` called through ctypes instead, which lets the GIL go.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
from collections.abc import Callable

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


@functools.cache
def _unlocked_finish() -> Callable[[], None] | None:
    """``glFinish`` of the current context through ctypes (which releases the GIL while it runs),
    looked up with ``eglGetProcAddress``; None where EGL does not give it."""
    try:
        egl = ctypes.CDLL(ctypes.util.find_library("EGL") or "libEGL.so.1")
        lookup = egl.eglGetProcAddress
    except (OSError, AttributeError):
        return None
    lookup.restype, lookup.argtypes = ctypes.c_void_p, [ctypes.c_char_p]
    address = lookup(b"glFinish")
    return None if not address else ctypes.CFUNCTYPE(None)(address)


def finish(ctx: moderngl.Context) -> None:
    """Wait until ``ctx`` (current on this thread, as moderngl keeps it) has done its GL work, as
    ``ctx.finish()`` does, but without holding the GIL meanwhile."""
    unlocked = _unlocked_finish()
    if unlocked is None:
        ctx.finish()
    else:
        unlocked()
