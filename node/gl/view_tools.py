"""A frame's tools as the nodes draw them (issue 35): clip planes and a section box, cut faces
capped in a solid colour, the selected object tinted. Part of the frame-synchronous state: each
``render`` carries them, so every tile of a frame cuts and tints alike.

* **Cutting.** The first :data:`MAX_CLIP_DISTANCES` half-spaces (:meth:`ClipState.halfspaces`:
  the planes, then the box's faces) are GL clip distances, written by the vertex shader from the
  world position: triangles are cut where they cross, before rasterization, so fragments are
  shaded only where kept and the depth test still runs before the shader. Half-spaces beyond them
  (a box with more than two planes) are tested per fragment, by the program variant with discards.
* **Culling.** The renderer's culler adds the half-spaces to each tile's frustum planes: a chunk
  wholly cut away is not drawn at all (:func:`tessera.tools.clipping.clipped_boxes`).
* **Caps.** With a cut active, a fragment whose normal points to the side of its triangle turned
  away from the eye (the triangle's facing taken from the screen-space derivatives of the position,
  whatever its winding), the inside of a closed surface seen through the cut, is drawn in the cap
  colour, flat: the cut face looks solid. Open surfaces show their inside in it too.
* **Highlight.** The batches of the selected object and its descendants are tinted
  (:data:`HIGHLIGHT_TINT`) after tone mapping.

GL's clip-distance enables are context state shared by every scene a node holds, so
:meth:`ViewToolsGL.bind` sets them before each draw.
"""

from __future__ import annotations

from dataclasses import dataclass

import moderngl
import numpy as np

from node.scene.data import SceneData
from tessera.tools.clipping import ClipState
from tessera.wire.messages import Render

GL_CLIP_DISTANCE0 = 0x3000
#: Clip distances the shaders write (GL guarantees at least 8).
MAX_CLIP_DISTANCES = 8
#: Half-spaces beyond the clip distances, tested per fragment (6 planes + a box = 12).
MAX_CLIP_DISCARDS = 4
#: The selected object's tint: sRGB colour and how much of it is mixed in.
HIGHLIGHT_TINT = (1.0, 0.72, 0.12, 0.45)
NO_TINT = (0.0, 0.0, 0.0, 0.0)
#: A plane every point is on the kept side of (distance 1).
KEEP_ALL = (0.0, 0.0, 0.0, 1.0)
#: GLSL of a vertex shader that cuts: ``world_position(position)`` is the object's vertex moved by
#: ``u_model``, its clip distances written.
CLIP_VERTEX = """
uniform mat4 u_model;
uniform vec4 u_clip[8];   // the frame's clip half-spaces (node.gl.view_tools): kept where dot >= 0
out float gl_ClipDistance[8];
vec4 world_position(vec3 position) {
    vec4 world = u_model * vec4(position, 1.0);
    for (int i = 0; i < 8; ++i) gl_ClipDistance[i] = dot(u_clip[i], world);
    return world;
}
"""
#: GLSL of a fragment shader that cuts what the clip distances cannot: ``cut_away(world position)``.
CLIP_FRAGMENT = """
uniform vec4 u_clip_extra[4];   // clip half-spaces beyond the 8 clip distances
uniform int u_clip_extra_count;
bool cut_away(vec3 position) {
    for (int i = 0; i < u_clip_extra_count; ++i)
        if (dot(u_clip_extra[i].xyz, position) + u_clip_extra[i].w < 0.0) return true;
    return false;
}
"""


@dataclass(frozen=True, slots=True)
class ViewTools:
    """What of the frame's tools a draw takes: the ``clip`` state (None: nothing cut) and the
    ``highlight``\\ ed object's name (None: none)."""

    clip: ClipState | None = None
    highlight: str | None = None

    @classmethod
    def of(cls, render: Render) -> ViewTools:
        return cls(render.clip, render.highlight)


def subtree(parents: np.ndarray, root: int) -> np.ndarray:
    """(N,) bool: object ``root`` and its descendants, of objects whose ``parents`` (N,) int64 come
    before them (−1: a root)."""
    inside = np.zeros(parents.size, dtype=bool)
    inside[root] = True
    for number in range(root + 1, parents.size):
        inside[number] = parents[number] >= 0 and inside[parents[number]]
    return inside


class ViewToolsGL:
    """The tools one renderer draws with (:meth:`use`), as uniforms of its programs and GL state."""

    def __init__(self, ctx: moderngl.Context, scene: SceneData) -> None:
        self.ctx, self.scene = ctx, scene
        self.tools = ViewTools()
        self.distances = 0
        self.halfspaces = np.zeros((0, 4))
        self._owners = np.array([b.owner for b in scene.batches], np.int64)
        self._tinted = np.zeros(len(scene.batches), dtype=bool)
        self._uniforms: dict[str, object] = {}

    @property
    def discards(self) -> bool:
        """More half-spaces than clip distances: draw with the program variant with discards."""
        return self.halfspaces.shape[0] > MAX_CLIP_DISTANCES

    def use(self, tools: ViewTools | None) -> bool:
        """Draw with ``tools`` (None: none) from now on; True when they changed (set the uniforms
        again: :meth:`uniforms`). ValueError for more half-spaces than can be drawn; a highlight of
        an object the scene lacks tints nothing (the coordinator checks names; a scene may change)."""
        tools = tools or ViewTools()
        if tools == self.tools:
            return False
        clip = tools.clip if tools.clip is not None and tools.clip.active else None
        halfspaces = np.zeros((0, 4)) if clip is None else clip.halfspaces()
        if halfspaces.shape[0] > MAX_CLIP_DISTANCES + MAX_CLIP_DISCARDS:
            raise ValueError(f"{halfspaces.shape[0]} clip half-spaces, at most "
                             f"{MAX_CLIP_DISTANCES + MAX_CLIP_DISCARDS} can be drawn")
        tinted = np.zeros(len(self.scene.batches), dtype=bool)
        number = None if tools.highlight is None else self.scene.objects.index.get(tools.highlight)
        if number is not None:
            tinted = subtree(self.scene.objects.parents, number)[self._owners]
        rows = [tuple(row) for row in halfspaces.tolist()]
        distances = rows[:MAX_CLIP_DISTANCES]
        extra = rows[MAX_CLIP_DISTANCES:]
        self.tools, self.halfspaces, self._tinted = tools, halfspaces, tinted
        self.distances = len(distances)
        self._uniforms = {
            "u_clip": distances + [KEEP_ALL] * (MAX_CLIP_DISTANCES - len(distances)),
            "u_clip_extra": extra + [KEEP_ALL] * (MAX_CLIP_DISCARDS - len(extra)),
            "u_clip_extra_count": len(extra),
            "u_cap": clip is not None and clip.cap is not None,
            "u_cap_color": tuple(clip.cap) if clip is not None and clip.cap is not None else (0.0, 0.0, 0.0),
        }
        return True

    def uniforms(self) -> dict[str, object]:
        """The uniforms of the tools in use, by name (those a program lacks are skipped)."""
        return self._uniforms or self._defaults()

    def _defaults(self) -> dict[str, object]:
        self._uniforms = {"u_clip": [KEEP_ALL] * MAX_CLIP_DISTANCES, "u_clip_extra": [KEEP_ALL] * MAX_CLIP_DISCARDS,
                          "u_clip_extra_count": 0, "u_cap": False, "u_cap_color": (0.0, 0.0, 0.0)}
        return self._uniforms

    def bind(self) -> None:
        """Enable this renderer's clip distances, disable the others (before each draw)."""
        for number in range(MAX_CLIP_DISTANCES):
            if number < self.distances:
                self.ctx.enable_direct(GL_CLIP_DISTANCE0 + number)
            else:
                self.ctx.disable_direct(GL_CLIP_DISTANCE0 + number)

    def tint(self, batch: int) -> tuple[float, float, float, float]:
        """The tint of batch ``batch`` (:data:`NO_TINT` unless it is the highlighted object's)."""
        return HIGHLIGHT_TINT if self._tinted[batch] else NO_TINT
