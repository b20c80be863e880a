"""Frame-sized framebuffers kept by size and sample count (:class:`FramebufferCache`): a session's
frames and a render job's pictures of another size do not reallocate each other's."""

from __future__ import annotations

import moderngl

#: Framebuffers a renderer keeps (sizes and sample counts), the least recently used released first.
FRAMEBUFFERS_KEPT = 4


class FramebufferCache:
    """Colour (RGBA8) and depth renderbuffers of each (size, samples) asked for, at most
    :data:`FRAMEBUFFERS_KEPT`, on ``ctx``."""

    def __init__(self, ctx: moderngl.Context) -> None:
        self.ctx = ctx
        #: By (size, samples), the most recently used last.
        self.kept: dict[tuple[tuple[int, int], int], moderngl.Framebuffer] = {}

    def get(self, size: tuple[int, int], samples: int = 1) -> moderngl.Framebuffer:
        """The ``size`` = (w, h) framebuffer with ``samples`` per pixel (1 or the multisample count)."""
        framebuffer = self.kept.pop((size, samples), None)
        if framebuffer is None:
            multisample = samples if samples > 1 else 0
            framebuffer = self.ctx.framebuffer(
                color_attachments=[self.ctx.renderbuffer(size, 4, samples=multisample)],
                depth_attachment=self.ctx.depth_renderbuffer(size, samples=multisample))
        self.kept[size, samples] = framebuffer
        while len(self.kept) > FRAMEBUFFERS_KEPT:
            _release(self.kept.pop(next(iter(self.kept))))
        return framebuffer

    def release(self) -> None:
        for framebuffer in self.kept.values():
            _release(framebuffer)
        self.kept.clear()


def _release(framebuffer: moderngl.Framebuffer) -> None:
    for attachment in (*framebuffer.color_attachments, framebuffer.depth_attachment):
        attachment.release()
    framebuffer.release()
