"""The one GL context factory: a headless moderngl context on EGL.

EGL picks the NVIDIA driver when its vendor library is installed (``/usr/share/glvnd/egl_vendor.d``)
and Mesa's llvmpipe otherwise. This is the only place a GL context is created.
"""

from __future__ import annotations

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
