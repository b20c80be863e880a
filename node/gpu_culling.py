"""GPU frustum culling with temporal coherence, and the hybrid CPU/GPU culler (seed 001 §6.1.2, §6.2).

The seed keeps the whole hierarchy on the GPU and processes only a set of input nodes in
parallel: the nodes the CPU processed last seed it; each frame's results are the next frame's
input; a node found outside the frustum puts its parent into the next input. Here a compute
shader (GL 4.3) runs one invocation per input node over the :class:`ChunkBVH` and writes the
glMultiDrawElementsIndirect commands itself, one slot per chunk (count 0 where culled), so the
frame draws with one ``render_indirect(commands, count=chunk_count)`` and nothing is read back.

Where the seed had to be interpreted:

- The seed's input is the visible nodes only, so chunks that come into view outside their subtrees
  would be missed until a parent climbs over them. Missing geometry is a hole in a tile, so here
  the input is always a *cut* of the tree (every chunk under exactly one input node): the CPU's
  last terminal nodes (culled, wholly inside, visible leaves; :attr:`CullResult.terminal_nodes`),
  or the root. An input node that is visible is traversed on the GPU (stack per invocation, plane
  masking) and its terminal nodes become next frame's input, so with a still camera the input
  settles on exactly the CPU's terminal set.
- An input node found outside puts its parent into the next input only when that parent is
  outside too (one more box test); otherwise the parent would be re-traversed and the node
  re-emitted on alternate frames. A second pass drops next-input nodes that have an ancestor in
  it, and duplicates, so the next input is again a cut.
- The result is exact (the same chunks as :func:`node.frustum_culling.cull`, up to float32
  rounding on planes and boxes), not a temporal approximation.

Frame tags that mark proposals wrap after 2³² frames (over two years at 60 Hz).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import moderngl
import numpy as np

from node.culling_state import CullDevice, HybridCullingSwitch, SwitchParams
from node.frustum_culling import ChunkBVH, cull, indirect_commands, merge_ranges, range_members

_GROUP = 64

_COMMON = """
#version 430
layout(local_size_x = 64) in;
struct Node { vec4 lo; vec4 hi; ivec4 tree; };   // tree: left child (-1 leaf), parent, first, end chunk
layout(std430, binding = 0) readonly buffer Nodes { Node nodes[]; };
layout(std430, binding = 2) buffer Proposals { uint proposal_count; uint proposals[]; };
layout(std430, binding = 3) buffer Marks { uint marks[]; };
uniform uint tag;
"""

_CULL_SOURCE = _COMMON + """
layout(std430, binding = 1) readonly buffer Spans { uvec2 spans[]; };   // chunk: first index, index count
layout(std430, binding = 4) writeonly buffer Commands { uint commands[]; };
layout(std430, binding = 5) readonly buffer Input { uint input_count; uint input_nodes[]; };
uniform vec4 planes[6];
const int OUTSIDE = 0, PARTIAL = 1, INSIDE = 2;

int classify(int n, inout uint mask) {
    vec3 center = (nodes[n].lo.xyz + nodes[n].hi.xyz) * 0.5;
    vec3 extent = (nodes[n].hi.xyz - nodes[n].lo.xyz) * 0.5;
    for (int i = 0; i < 6; ++i) {
        if ((mask & (1u << i)) == 0u) continue;
        float d = dot(center, planes[i].xyz) + planes[i].w;
        float r = dot(extent, abs(planes[i].xyz));
        if (d + r < 0.0) return OUTSIDE;
        if (d - r >= 0.0) mask &= ~(1u << i);
    }
    return mask == 0u ? INSIDE : PARTIAL;
}

void write_commands(int n, bool visible) {
    int first = nodes[n].tree.z, end = nodes[n].tree.w;
    for (int c = first; c < end; ++c) {
        bool head = visible && c == first;
        uint first_index = spans[first].x;
        commands[5 * c + 0] = head ? spans[end - 1].x + spans[end - 1].y - first_index : 0u;
        commands[5 * c + 1] = head ? 1u : 0u;
        commands[5 * c + 2] = head ? first_index : 0u;
        commands[5 * c + 3] = 0u;
        commands[5 * c + 4] = 0u;
    }
}

void propose(int n) {
    proposals[atomicAdd(proposal_count, 1u)] = uint(n);
    marks[n] = tag;
}

void main() {
    uint gid = gl_GlobalInvocationID.x;
    if (gid >= input_count) return;
    int root = int(input_nodes[gid]);
    uint mask = 63u;
    if (classify(root, mask) == OUTSIDE) {
        write_commands(root, false);
        int parent = nodes[root].tree.y;
        uint parent_mask = 63u;
        propose(parent >= 0 && classify(parent, parent_mask) == OUTSIDE ? parent : root);
        return;
    }
    int stack_node[64];
    uint stack_mask[64];
    int top = 0;
    stack_node[0] = root;
    stack_mask[0] = 63u;
    while (top >= 0) {
        int n = stack_node[top];
        uint m = stack_mask[top];
        --top;
        int result = classify(n, m);
        int left = nodes[n].tree.x;
        if (result == OUTSIDE || result == INSIDE || left < 0) {
            write_commands(n, result != OUTSIDE);
            propose(n);
        } else {
            stack_node[++top] = left + 1;
            stack_mask[top] = m;
            stack_node[++top] = left;
            stack_mask[top] = m;
        }
    }
}
"""

_SETTLE_SOURCE = _COMMON + """
layout(std430, binding = 4) buffer Claims { uint claims[]; };
layout(std430, binding = 5) buffer Next { uint next_count; uint next_nodes[]; };

void main() {
    uint gid = gl_GlobalInvocationID.x;
    if (gid >= proposal_count) return;
    int n = int(proposals[gid]);
    for (int a = nodes[n].tree.y; a >= 0; a = nodes[a].tree.y)
        if (marks[a] == tag) return;
    if (atomicExchange(claims[n], tag) == tag) return;
    next_nodes[atomicAdd(next_count, 1u)] = uint(n);
}
"""


class GpuBvh:
    """A :class:`ChunkBVH` and its chunks' index spans uploaded once (SSBOs), with both shaders.

    ``index_starts``/``index_ends`` (C,) are each chunk's index range in the shared index buffer;
    chunks must be contiguous (chunk i ends where i + 1 starts), as :class:`ChunkSplit` gives them.
    """

    def __init__(self, ctx: moderngl.Context, bvh: ChunkBVH, index_starts: np.ndarray,
                 index_ends: np.ndarray) -> None:
        if ctx.version_code < 430:
            raise RuntimeError(f"GPU culling needs GL 4.3 compute shaders, context is {ctx.version_code}")
        starts = np.asarray(index_starts, dtype=np.int64)
        ends = np.asarray(index_ends, dtype=np.int64)
        if starts.size != bvh.chunk_count or np.any(starts[1:] != ends[:-1]):
            raise ValueError("GpuBvh needs one contiguous index range per chunk, in chunk order")
        self.ctx, self.bvh = ctx, bvh
        self.index_starts, self.index_ends = starts, ends
        nodes = np.zeros(bvh.node_count, [("lo", "f4", 4), ("hi", "f4", 4), ("tree", "i4", 4)])
        nodes["lo"][:, :3], nodes["hi"][:, :3] = bvh.lo, bvh.hi
        nodes["tree"] = np.stack([bvh.left, bvh.parent, bvh.first_chunk, bvh.end_chunk], axis=1)
        self.nodes = ctx.buffer(nodes.tobytes())
        self.spans = ctx.buffer(np.stack([starts, ends - starts], axis=1).astype(np.uint32).tobytes())
        self.cull_shader = ctx.compute_shader(_CULL_SOURCE)
        self.settle_shader = ctx.compute_shader(_SETTLE_SOURCE)

    @property
    def chunk_count(self) -> int:
        return self.bvh.chunk_count


class GpuCuller:
    """One tile slot's temporal-coherence culler: its input cut (ping-pong), marks and commands.

    ``commands`` is a (C, 5) uint32 buffer of DrawElementsIndirectCommand rows, rewritten by every
    :meth:`cull`; draw with ``vao.render_indirect(culler.commands, count=culler.command_count)``.
    """

    def __init__(self, gpu_bvh: GpuBvh) -> None:
        self.gpu_bvh = gpu_bvh
        ctx, node_total = gpu_bvh.ctx, gpu_bvh.bvh.node_count
        header_and_nodes = bytes(4 * (node_total + 1))
        self._inputs = [ctx.buffer(header_and_nodes), ctx.buffer(header_and_nodes)]
        self._proposals = ctx.buffer(header_and_nodes)
        self._marks = ctx.buffer(bytes(4 * node_total))      # frame tag of the last proposal per node
        self._claims = ctx.buffer(bytes(4 * node_total))     # frame tag of the last settled node
        self.commands = ctx.buffer(bytes(20 * gpu_bvh.chunk_count))
        self._tag = 0
        self.seed(np.zeros(1, np.int32))

    @property
    def command_count(self) -> int:
        return self.gpu_bvh.chunk_count

    def seed(self, cut_nodes: np.ndarray) -> None:
        """Start from ``cut_nodes`` (T,) — a cut of the tree, e.g. the CPU's terminal nodes."""
        nodes = np.asarray(cut_nodes, dtype=np.int64)
        bvh = self.gpu_bvh.bvh
        covered = np.sort(range_members(bvh.first_chunk[nodes], bvh.end_chunk[nodes]))
        if not np.array_equal(covered, np.arange(bvh.chunk_count)):
            raise ValueError("seed nodes must be a cut of the tree: every chunk under exactly one of them")
        self._inputs[0].write(np.concatenate(([nodes.size], nodes)).astype(np.uint32).tobytes())

    def cull(self, planes: np.ndarray) -> None:
        """Cull against ``planes`` (6, 4) world space; rewrites :attr:`commands` on the GPU."""
        gpu, ctx = self.gpu_bvh, self.gpu_bvh.ctx
        self._tag += 1
        zero = np.zeros(1, np.uint32).tobytes()
        self._proposals.write(zero)
        self._inputs[1].write(zero)
        groups = -(-gpu.bvh.node_count // _GROUP)
        gpu.nodes.bind_to_storage_buffer(0)
        self._proposals.bind_to_storage_buffer(2)
        self._marks.bind_to_storage_buffer(3)
        gpu.spans.bind_to_storage_buffer(1)
        self.commands.bind_to_storage_buffer(4)
        self._inputs[0].bind_to_storage_buffer(5)
        gpu.cull_shader["planes"].write(np.asarray(planes, dtype=np.float32).tobytes())
        gpu.cull_shader["tag"].value = self._tag
        gpu.cull_shader.run(groups)
        ctx.memory_barrier(moderngl.SHADER_STORAGE_BARRIER_BIT)
        self._claims.bind_to_storage_buffer(4)
        self._inputs[1].bind_to_storage_buffer(5)
        gpu.settle_shader["tag"].value = self._tag
        gpu.settle_shader.run(groups)
        ctx.memory_barrier(moderngl.SHADER_STORAGE_BARRIER_BIT | moderngl.COMMAND_BARRIER_BIT)
        self._inputs.reverse()

    def read_commands(self) -> np.ndarray:
        """(C, 5) uint32 commands of the last cull (a GPU→CPU read: waits for the GPU)."""
        return np.frombuffer(self.commands.read(), np.uint32).reshape(-1, 5)

    def read_visible_chunks(self) -> np.ndarray:
        """(K,) int64 sorted ids of the chunks the last cull kept (reads the commands back)."""
        commands = self.read_commands()
        drawn = commands[commands[:, 0] > 0]
        first = np.searchsorted(self.gpu_bvh.index_starts, drawn[:, 2])
        end = np.searchsorted(self.gpu_bvh.index_starts, drawn[:, 2].astype(np.int64) + drawn[:, 0])
        return np.sort(range_members(first, end))

    def read_input_nodes(self) -> np.ndarray:
        """(T,) uint32 the input cut for the next cull."""
        data = np.frombuffer(self._inputs[0].read(), np.uint32)
        return np.sort(data[1:1 + data[0]])


@dataclass(frozen=True, slots=True)
class TileDraw:
    """What to draw for one tile: ``indirect`` (a (N, 5) uint32 command buffer) with
    ``command_count`` rows, drawn by ``vao.render_indirect(indirect, count=command_count)``;
    ``ranges`` (start, count) in indices when the CPU culled (None on the GPU path)."""

    device: CullDevice
    indirect: moderngl.Buffer
    command_count: int
    ranges: list[tuple[int, int]] | None


class HybridCuller:
    """Seed 001's hybrid culling for the tiles of one node: per tile slot, a switch
    (:class:`HybridCullingSwitch`) fed with measured CPU culling times picks CPU or GPU culling."""

    def __init__(self, gpu_bvh: GpuBvh, params: SwitchParams = SwitchParams()) -> None:
        self.gpu_bvh, self.params = gpu_bvh, params
        self._slots: dict[object, tuple[HybridCullingSwitch, GpuCuller, moderngl.Buffer]] = {}

    def cull(self, slot: object, planes: np.ndarray) -> TileDraw:
        """Cull tile ``slot`` (any key, e.g. the tile's index on this node) against ``planes`` (6, 4)."""
        if slot not in self._slots:
            self._slots[slot] = (HybridCullingSwitch.start(self.params), GpuCuller(self.gpu_bvh),
                                 self.gpu_bvh.ctx.buffer(reserve=20 * self.gpu_bvh.chunk_count))
        switch, gpu_culler, cpu_commands = self._slots[slot]
        if switch.device is CullDevice.GPU:
            gpu_culler.cull(planes)
            self._slots[slot] = (switch.step(None), gpu_culler, cpu_commands)
            return TileDraw(CullDevice.GPU, gpu_culler.commands, gpu_culler.command_count, None)
        began = time.perf_counter()
        result = cull(self.gpu_bvh.bvh, planes)
        elapsed = time.perf_counter() - began
        ranges = merge_ranges(result.visible_chunks, self.gpu_bvh.index_starts, self.gpu_bvh.index_ends)
        next_switch = switch.step(elapsed)
        if next_switch.device is CullDevice.GPU:
            gpu_culler.seed(result.terminal_nodes)
        self._slots[slot] = (next_switch, gpu_culler, cpu_commands)
        if ranges:
            cpu_commands.write(indirect_commands(ranges).tobytes())
        return TileDraw(CullDevice.CPU, cpu_commands, len(ranges), ranges)
