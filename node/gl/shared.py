"""What the tile renderers of one GL context share (:class:`SharedGL`): the frame-sized
framebuffers and the environment's lighting textures. A node holds a renderer per scene and
makes a new one for each mesh step of a simulation (issue 33); sharing these, a new scene's first
tile allocates no framebuffer (about 10 ms at 640x360's 3x3 samples on llvmpipe, with the first
writes into fresh pages) and its upload no lighting texture (about 3 ms)."""

from __future__ import annotations

from pathlib import Path

import moderngl

from node.gl.framebuffers import FramebufferCache
from node.gl.image_lighting import ImageLighting, prefiltered_environment


class SharedGL:
    """The framebuffers (:class:`FramebufferCache`) and the lighting of each environment file
    (None: the studio) of renderers on ``ctx``; used on the thread that owns ``ctx``, released
    once with it."""

    def __init__(self, ctx: moderngl.Context) -> None:
        self.ctx = ctx
        self.framebuffers = FramebufferCache(ctx)
        self._lighting: dict[Path | None, ImageLighting] = {}

    def lighting(self, environment: Path | None) -> ImageLighting:
        """The lighting textures of ``environment`` (a Radiance .hdr; None: the studio), made on
        first use. Raises :class:`node.gl.environment.EnvironmentError`."""
        lighting = self._lighting.get(environment)
        if lighting is None:
            lighting = self._lighting[environment] = ImageLighting(self.ctx, prefiltered_environment(environment))
        return lighting

    def release(self) -> None:
        self.framebuffers.release()
        for lighting in self._lighting.values():
            lighting.release()
        self._lighting.clear()
