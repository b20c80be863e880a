"""Per-tile culling for the renderer (seed 001 §6): off, CPU, GPU, or hybrid — the CPU↔GPU switch of
Fig. 6.4 (:class:`node.culling.switch.HybridCullingSwitch`, the seed's parameters by default) run
per tile slot, because the coordinator hands a node the same tile slot frame after frame and the
switch needs one tile's timings over consecutive frames. The tree over the scene's chunks
(:func:`node.culling.bvh.build_chunk_bvh`) is built here, when the renderer makes its culler.

- CPU: :func:`node.culling.bvh.cull` over the chunk tree; the kept chunks become index runs per
  batch, nearest first (:func:`node.culling.order.front_to_back`), written as indirect draw commands.
  Its time (tree test + runs, perf_counter) is what the hybrid switch reads as the CPU culling time.
- GPU: a :class:`node.culling.gpu.GpuCuller` per tile slot writes one indirect command per chunk;
  its cull time is the CPU-side time of the two dispatches (on llvmpipe the compute shaders run
  on the CPU). When the switch hands a slot over to the GPU, the slot's GPU input is seeded with
  the CPU's last terminal nodes (seed 001 §6.1.2).
- Hybrid: CPU until the switch says GPU, and back.
- Moved objects (issue 11): their batches are left out of the above (the tree is at the base
  pose) and culled on the CPU in every mode but off by :meth:`TileCuller.cull_moved`, in their own
  frame (:mod:`node.culling.objects`).
- Auto (the default): hybrid on a hardware GPU, CPU on a software rasterizer
  (:func:`node.culling.switch.resolve_culling`).

Either way a tile is drawn the same way (:class:`TileCull`): per batch, one
glMultiDrawElementsIndirect over its slice of a command buffer. On llvmpipe that ties with one
``render(first=, vertices=)`` per run, since Mesa loops over the commands in C at the same cost a
draw either way; multi-draw is kept for one draw path for both culling devices and no Python call
per run (docs/explanation/culling.md).

On llvmpipe the GPU path loses: its compute shaders run on the same CPU cores, cull slower than
the CPU traversal, and the seed's 0.3 ms threshold, which the CPU cull time straddles on a shared
machine, sends many tiles to them (docs/explanation/culling.md). The seed's parameters stay the defaults (a
real GPU is what they were chosen for), and the default mode ``auto`` culls on the CPU on llvmpipe.

What ran is reported per tile: the path, chunks drawn, triangles submitted and the culling time. On
the GPU path the counts are read back from the command buffer after drawing.
"""

from __future__ import annotations

import time
from collections.abc import Hashable, Sequence
from dataclasses import dataclass, field

import moderngl
import numpy as np

from node.culling.bvh import build_chunk_bvh, cull
from node.culling.frustum import frustum_planes_from_matrix
from node.culling.gpu import GpuBvh, GpuCuller
from node.culling.lod import LodCut, subtract_ranges
from node.culling.objects import MovedCuller
from node.culling.order import ChunkGroups, front_to_back
from node.culling.switch import CullDevice, CullMode, HybridCullingSwitch, SwitchParams, resolve_culling
from node.scene.chunks import DrawRuns, SceneChunks
from tessera.geometry import Rect
from tessera.tools.clipping import clipped_boxes


class CullingUnavailableError(RuntimeError):
    """``--culling gpu`` on a context without GL 4.3 compute shaders."""


@dataclass(frozen=True, slots=True)
class TileCull:
    """One tile's culling outcome, ready to draw: for each ``(batch, first, count)`` in ``batches``
    (draw order), ``count`` DrawElementsIndirectCommand rows of ``commands`` from row ``first``.
    ``path`` is "off", "cpu", "gpu" or "list" (chunks given, :meth:`TileCuller.listed`); ``cull_ms``
    the culling time; ``runs`` the index runs the commands hold (None on the GPU path, whose
    commands stay on the GPU)."""

    path: str
    cull_ms: float
    commands: moderngl.Buffer
    batches: list[tuple[int, int, int]]
    runs: DrawRuns | None


@dataclass(frozen=True, slots=True)
class CullCounts:
    """What a tile drew: ``chunks_drawn`` (of the scene's chunks) and ``triangles`` submitted."""

    chunks_drawn: int
    triangles: int


@dataclass
class _Slot:
    switch: HybridCullingSwitch
    gpu: GpuCuller | None = field(default=None)


class TileCuller:
    """Culls tiles of one scene on one GL context (the renderer's thread) in ``mode``: builds the
    tree over the scene's chunks (:attr:`bvh`) and, per tile slot, keeps the hybrid switch and, once
    the slot has culled on the GPU, its GPU culler.

    GPU and hybrid culling need GL 4.3 compute shaders: without them ``mode`` gpu raises
    CullingUnavailableError and hybrid stays on the CPU (its switch is not fed). ``mode`` auto is
    resolved for ``ctx``'s renderer; :attr:`mode` is what runs.
    """

    def __init__(self, ctx: moderngl.Context, chunks: SceneChunks, mode: CullMode = CullMode.AUTO,
                 params: SwitchParams = SwitchParams()) -> None:
        mode = resolve_culling(mode, ctx.info["GL_RENDERER"])
        if mode is CullMode.GPU and ctx.version_code < 430:
            raise CullingUnavailableError(f"--culling gpu needs GL 4.3 compute shaders; this context is GL "
                                          f"{ctx.version_code // 100}.{ctx.version_code % 100 // 10}")
        self.chunks, self.mode, self.params = chunks, mode, params
        self.bvh = build_chunk_bvh(chunks.boxes) if chunks.tree is None else chunks.tree
        self.groups = ChunkGroups.of(chunks)
        #: Moved objects' batches, culled on the CPU in every mode but off (:mod:`node.culling.objects`).
        self.moved = MovedCuller(chunks)
        self._slots: dict[Hashable, _Slot] = {}
        self._cpu_commands = ctx.buffer(reserve=20 * chunks.chunk_count)   # runs never outnumber chunks
        self._all_runs = chunks.all_runs()
        self._all_commands = ctx.buffer(indirect_commands(_run_spans(self._all_runs)).tobytes())
        bounds = chunks.batch_bounds
        self._gpu_batches = [(b, int(bounds[b]), int(bounds[b + 1] - bounds[b])) for b in range(bounds.size - 1)]
        self.gpu_bvh: GpuBvh | None = None
        #: The frame's clip half-spaces (P, 4) world space (None: nothing cut) and the chunks they
        #: cut away wholly (:meth:`set_clip`).
        self.clip: np.ndarray | None = None
        self._clipped: np.ndarray | None = None
        if mode in (CullMode.GPU, CullMode.HYBRID) and ctx.version_code >= 430:
            index = chunks.index_bounds
            self.gpu_bvh = GpuBvh(ctx, self.bvh, index[:-1], index[1:], bounds[chunks.batch + 1])

    @property
    def takes_levels(self) -> bool:
        """Whether its tiles can leave out chunks a level of detail stands in for: every mode but gpu,
        whose compute shader draws every chunk it keeps (hybrid culls a tile with coarse levels on
        the CPU)."""
        return self.mode is not CullMode.GPU

    def cull(self, slot: Hashable, view_proj: np.ndarray, size: tuple[int, int], rect: Rect,
             lod: LodCut | None = None) -> TileCull:
        """Cull tile ``slot`` (any key: the tile's id), the ``rect`` part of a ``size`` frame drawn
        with the full-frame ``view_proj`` (4, 4) world→clip matrix; the chunks ``lod``'s coarse nodes
        stand in for are left out (:attr:`takes_levels` modes only)."""
        coarse = lod is not None and lod.coarse
        if self.mode is CullMode.OFF and not coarse:
            return TileCull("off", 0.0, self._all_commands, self._all_runs.batch_slices(), self._all_runs)
        if self.mode is CullMode.OFF:
            assert lod is not None
            first, end = subtract_ranges(np.zeros(1, np.int64), np.array([self.chunks.chunk_count]),
                                         lod.blocked_first, lod.blocked_end)
            return self._written("off", 0.0, self.chunks.runs(first, end))
        planes = frustum_planes_from_matrix(view_proj, size, rect)
        state = self._slots.get(slot)
        if state is None:
            state = self._slots[slot] = _Slot(HybridCullingSwitch.start(self.params))
        if self.clip is not None:   # chunks wholly cut away are culled like those outside the tile
            return self._cull_cpu(state, np.vstack((planes, self.clip)), view_proj, lod if coarse else None)
        if self.mode is CullMode.GPU or (state.switch.device is CullDevice.GPU and not coarse):
            return self._cull_gpu(state, planes)
        return self._cull_cpu(state, planes, view_proj, lod if coarse else None)

    def cull_moved(self, view_proj: np.ndarray, size: tuple[int, int], rect: Rect, batches: Sequence[int],
                   models: np.ndarray) -> DrawRuns:
        """The runs of moved ``batches`` (sorted ids) that the ``rect`` tile keeps, each batch moved by
        its row of ``models`` (len, 4, 4) (:meth:`MovedCuller.cull`; mode off: all of them)."""
        planes = (None if self.mode is CullMode.OFF or not batches
                  else frustum_planes_from_matrix(view_proj, size, rect))
        if planes is not None and self.clip is not None:
            planes = np.vstack((planes, self.clip))
        return self.moved.cull(planes, batches, models)

    def set_clip(self, halfspaces: np.ndarray | None) -> None:
        """Cull the chunks wholly outside one of the world ``halfspaces`` (P, 4) too (None: none),
        on the CPU (the GPU path tests six planes; the clip distances cut what it keeps)."""
        self.clip = None if halfspaces is None else np.asarray(halfspaces, dtype=np.float64).reshape(-1, 4)
        self._clipped = None if self.clip is None else clipped_boxes(self.chunks.boxes, self.clip)

    def listed(self, chunk_ids: np.ndarray, view_proj: np.ndarray | None = None, lod: LodCut | None = None) -> TileCull:
        """Draw exactly ``chunk_ids`` (K,) sorted, unique chunk ids, no culling: what a depth layer
        draws when hybrid ownership or a sort-last share decided (path "list"); nearest first under
        the full-frame ``view_proj`` when given (:func:`node.culling.order.front_to_back`); but the
        chunks ``lod``'s coarse nodes stand in for."""
        ids = np.asarray(chunk_ids, dtype=np.int64)
        if self._clipped is not None and ids.size:
            ids = ids[~self._clipped[ids]]
        heads = np.flatnonzero(np.diff(ids, prepend=-2) != 1)
        first, end = ids[heads], np.append(ids[heads[1:] - 1], ids[-1:]) + 1
        if lod is not None and lod.coarse:
            first, end = subtract_ranges(first, end, lod.blocked_first, lod.blocked_end)
        runs = (self.chunks.runs(first, end) if view_proj is None
                else front_to_back(self.chunks, self.groups, first, end, view_proj))
        return self._written("list", 0.0, runs)

    def _written(self, path: str, cull_ms: float, runs: DrawRuns) -> TileCull:
        """``runs`` written as the CPU's indirect commands."""
        if runs.batch.size:
            self._cpu_commands.write(indirect_commands(_run_spans(runs)).tobytes())
        return TileCull(path, cull_ms, self._cpu_commands, runs.batch_slices(), runs)

    def _gpu_culler(self) -> GpuCuller:
        assert self.gpu_bvh is not None
        return GpuCuller(self.gpu_bvh)

    def _cull_cpu(self, state: _Slot, planes: np.ndarray, view_proj: np.ndarray, lod: LodCut | None) -> TileCull:
        started = time.perf_counter()
        result = cull(self.bvh, planes, None if lod is None else lod.hidden)
        first, end = result.visible_first, result.visible_end
        if lod is not None:
            first, end = subtract_ranges(first, end, lod.blocked_first, lod.blocked_end)
        runs = front_to_back(self.chunks, self.groups, first, end, view_proj)
        elapsed = time.perf_counter() - started
        if self.mode is CullMode.HYBRID and self.gpu_bvh is not None and state.switch.device is CullDevice.CPU:
            state.switch = state.switch.step(elapsed)   # a GPU stint's coarse or clipped tile leaves it be
            if state.switch.device is CullDevice.GPU:
                state.gpu = state.gpu or self._gpu_culler()
                state.gpu.seed(result.terminal_nodes)
        return self._written("cpu", elapsed * 1e3, runs)

    def _cull_gpu(self, state: _Slot, planes: np.ndarray) -> TileCull:
        state.gpu = state.gpu or self._gpu_culler()
        started = time.perf_counter()
        state.gpu.cull(planes)
        elapsed = time.perf_counter() - started
        if self.mode is CullMode.HYBRID:
            state.switch = state.switch.step(None)
        return TileCull("gpu", elapsed * 1e3, state.gpu.commands, self._gpu_batches, None)

    def counts(self, tile: TileCull, skip: np.ndarray | None = None) -> CullCounts:
        """Chunks drawn and triangles submitted by ``tile`` (reads a GPU tile's commands back),
        leaving out the batches ``skip`` (B,) bool marks (the renderer did not draw them from ``tile``)."""
        runs = tile.runs
        if runs is not None and skip is None:
            return CullCounts(runs.chunks, runs.triangles)
        if runs is not None:
            keep = ~skip[runs.batch]
            first, count = runs.first[keep], runs.count[keep]
            bounds = self.chunks.index_bounds
            chunks = np.searchsorted(bounds, first + count) - np.searchsorted(bounds, first)
            return CullCounts(int(chunks.sum()), int(count.sum()) // 3)
        commands = np.frombuffer(tile.commands.read(), np.uint32).reshape(-1, 5)
        heads = np.flatnonzero(commands[:, 0])
        if skip is not None:
            heads = heads[~skip[self.chunks.batch[heads]]]
        counts = commands[heads, 0].astype(np.int64)
        ends = np.searchsorted(self.chunks.index_bounds, commands[heads, 2].astype(np.int64) + counts)
        return CullCounts(int((ends - heads).sum()), int(counts.sum()) // 3)

    def release(self) -> None:
        """Free the command buffers and the GPU culling buffers and shaders."""
        for state in self._slots.values():
            if state.gpu is not None:
                state.gpu.release()
        self._slots.clear()
        if self.gpu_bvh is not None:
            self.gpu_bvh.release()
            self.gpu_bvh = None
        self._cpu_commands.release()
        self._all_commands.release()


def _run_spans(runs: DrawRuns) -> np.ndarray:
    """(R, 2) int64 (first index, index count) of ``runs``."""
    return np.stack([runs.first, runs.count], axis=1)


def indirect_commands(ranges: list[tuple[int, int]] | np.ndarray, base_vertex: int = 0) -> np.ndarray:
    """(N, 5) uint32 DrawElementsIndirectCommand rows (count, instanceCount, firstIndex, baseVertex,
    baseInstance) for index ``ranges`` (start, count), one instance each: upload and draw them all
    with one ``VertexArray.render_indirect(buffer, count=N)`` (glMultiDrawElementsIndirect)."""
    spans = np.asarray(ranges, dtype=np.int64).reshape(-1, 2)
    commands = np.zeros((spans.shape[0], 5), np.uint32)
    commands[:, 0] = spans[:, 1]
    commands[:, 1] = 1
    commands[:, 2] = spans[:, 0]
    commands[:, 3] = base_vertex
    return commands
