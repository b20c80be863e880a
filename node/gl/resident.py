"""The scenes a render node holds at once (issue 19: sessions time-share the nodes, so a node holds
several scenes and draws a tile of any of them, frame by frame): :class:`ResidentScenes`, each
loaded scene (:class:`ResidentScene`: its renderer with GL buffers of its own and what depth layers
are planned from) keyed by its spec and sort-last share, in least-recently-used order within a
memory budget. Used on the GL thread only (releasing a scene frees its GL objects), but
:meth:`ResidentScenes.holds`.

The memory a scene is counted for (:func:`estimated_bytes`) is what grows with its geometry: the
renderer's vertex and index buffers on the GPU plus the scene's arrays kept in host memory
(:attr:`node.scene.data.SceneData.nbytes`). Textures are counted once, in host memory; shaders,
the per-tile culling buffers and the frame-sized framebuffer are left out.
"""

from __future__ import annotations

import logging
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from node.gl.depth_layers import PlanningScene
from node.gl.point_renderer import PointRenderer
from node.gl.renderer import TileRenderer
from tessera.wire.messages import ShareSpec

log = logging.getLogger("tessera.node")

#: A loaded scene's key: its spec, and sort-last its share (index, weights; None: the whole scene).
SceneKey = tuple[str, tuple[int, tuple[float, ...]] | None]


def scene_key(spec: str, share: ShareSpec | None) -> SceneKey:
    """The key of scene ``spec`` loaded whole (``share`` None) or as ``share``: shares of the same
    index and weights hold the same chunks, whatever the partition's version."""
    return spec, None if share is None else (share.index, share.weights)


class SceneNotLoadedError(RuntimeError):
    """A tile of a scene (or share) this node does not hold; the message says which."""


def estimated_bytes(renderer: TileRenderer | PointRenderer) -> int:
    """Bytes a loaded scene is counted for: ``renderer``'s vertex and index buffers (and its levels
    of detail's) plus its scene's arrays held in memory (a point cloud's: :attr:`PointRenderer.nbytes`)."""
    if isinstance(renderer, PointRenderer):
        return renderer.nbytes
    levels = 0 if renderer.lod is None else renderer.lod.nbytes
    return renderer.vertex_buffer.size + renderer.index_buffer.size + levels + renderer.scene.nbytes


@dataclass(eq=False)
class ResidentScene:
    """A loaded scene: ``renderer`` draws it, ``planning`` plans its depth layers (None: a point
    cloud's, :mod:`node.gl.point_renderer`); ``share_version``
    the data partition version of the share held (None: the whole scene); ``nbytes``
    (:func:`estimated_bytes`); ``loaded`` orders the loads (a reload counts as one); ``entry``
    its scene cache entry (None: read into memory), where its levels of detail are built from."""

    key: SceneKey
    renderer: TileRenderer | PointRenderer
    planning: PlanningScene | None
    share_version: int | None
    nbytes: int
    loaded: int = 0
    entry: Path | None = None

    @property
    def spec(self) -> str:
        return self.key[0]


class ResidentScenes:
    """The scenes held, least recently used first, within ``budget_bytes`` (after each load the least
    recently used others are released until the total fits; the scene just loaded always stays)."""

    def __init__(self, budget_bytes: int) -> None:
        self.budget_bytes = budget_bytes
        self._scenes: OrderedDict[SceneKey, ResidentScene] = OrderedDict()
        self._levels_refused: set[SceneKey] = set()
        self._loads = 0

    @property
    def total_bytes(self) -> int:
        return sum(scene.nbytes for scene in self._scenes.values())

    def keys(self) -> list[SceneKey]:
        """The keys held, least recently used first."""
        return list(self._scenes)

    def reloaded(self, key: SceneKey) -> ResidentScene | None:
        """The scene of ``key`` asked for again (now the newest load and the most recently used),
        None when not held."""
        scene = self._scenes.get(key)
        if scene is not None:
            self._touch(scene)
        return scene

    def add(self, scene: ResidentScene) -> list[SceneKey]:
        """Hold ``scene`` (the newest load, the most recently used; one of its key already held is
        released), then release the least recently used others until the total fits the budget;
        returns the keys released for the budget."""
        old = self._scenes.pop(scene.key, None)
        if old is not None:
            old.renderer.release()
        self._scenes[scene.key] = scene
        self._touch(scene)
        return self.release_over_budget(scene.key)

    def release_over_budget(self, keep: SceneKey) -> list[SceneKey]:
        """Release the least recently used scenes but ``keep``'s until the total fits the budget;
        returns the keys released."""
        evicted = []
        while self.total_bytes > self.budget_bytes:
            key = next((key for key in self._scenes if key != keep), None)
            if key is None:
                break
            self._scenes.pop(key).renderer.release()
            evicted.append(key)
        return evicted

    def levels_fit(self, key: SceneKey, needed: int) -> bool:
        """Whether the scene of ``key`` fits the budget with its levels of detail, ``needed`` bytes in
        all; if not, it is drawn at full detail from now on (its levels refused: :meth:`levels_refused`; logged)."""
        if needed <= self.budget_bytes:
            return True
        self._levels_refused.add(key)
        log.warning("levels of detail of %s not held: with them it needs about %.0f MB, more than this node's "
                    "--scene-memory-mb %.0f; it is drawn at full detail (raise --scene-memory-mb, or serve it in "
                    "sort-last mode, where each node holds a share)", key[0], needed / (1 << 20),
                    self.budget_bytes / (1 << 20))
        return False

    def levels_refused(self, key: SceneKey) -> bool:
        """Whether the levels of detail of the scene of ``key`` were found not to fit (:meth:`levels_fit`)."""
        return key in self._levels_refused

    def holds(self, key: SceneKey) -> bool:
        """Whether the scene of ``key`` is held: one membership test, which any thread may make
        (scenes are added by the loads of :class:`node.gl.worker.GLWorker`, which asks while none of
        that key is under way)."""
        return key in self._scenes

    def held(self, key: SceneKey) -> ResidentScene | None:
        """The scene of ``key`` if held (its place in the order unchanged)."""
        return self._scenes.get(key)

    def find(self, spec: str | None, share: int | None = None) -> ResidentScene:
        """The scene a tile of ``spec`` is drawn from (None: the spec loaded last), marked most
        recently used: of its loads, the newest, or with ``share`` the one holding that partition
        version's share. Raises SceneNotLoadedError."""
        if spec is None:
            if not self._scenes:
                raise SceneNotLoadedError("no scene loaded")
            spec = max(self._scenes.values(), key=lambda scene: scene.loaded).spec
        held = [scene for scene in self._scenes.values() if scene.spec == spec]
        if not held:
            raise SceneNotLoadedError(f"scene {spec} is not loaded on this node")
        fitting = held if share is None else [scene for scene in held if scene.share_version == share]
        if not fitting:
            holds = ", ".join(sorted({f"{s.share_version}" if s.share_version else "the whole scene" for s in held}))
            raise SceneNotLoadedError(f"share of partition {share} of scene {spec} asked for; this node holds {holds}")
        scene = max(fitting, key=lambda scene: scene.loaded)
        self._scenes.move_to_end(scene.key)
        return scene

    def release(self, which: Callable[[SceneKey], bool]) -> None:
        """Release the scenes whose keys ``which`` picks."""
        for key in [key for key in self._scenes if which(key)]:
            self._scenes.pop(key).renderer.release()

    def release_all(self) -> None:
        for scene in self._scenes.values():
            scene.renderer.release()
        self._scenes.clear()

    def _touch(self, scene: ResidentScene) -> None:
        self._loads += 1
        scene.loaded = self._loads
        self._scenes.move_to_end(scene.key)
