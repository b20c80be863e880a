"""GPU frustum culling with temporal coherence (seed 001 §6.1.2); the hybrid CPU/GPU switching that
uses it is :mod:`node.culling.tiles`.

The seed keeps the whole hierarchy on the GPU and processes only a set of input nodes in
parallel: the nodes the CPU processed last seed it; each frame's results are the next frame's
input; a node found outside the frustum puts its parent into the next input. Here a compute
shader (GL 4.3) runs one invocation per input node over the :class:`ChunkBVH` and writes the
glMultiDrawElementsIndirect commands itself, one slot per chunk (count 0 where culled), so each
batch draws with one ``render_indirect(commands, count=its chunks, first=its first chunk)`` and
nothing needs to be read back.

Where the seed had to be interpreted:

- The seed's input is the visible nodes only, so chunks that come into view outside their subtrees
  would be missed until a parent climbs over them. Missing geometry is a hole in a tile, so here
  the input is always a *cut* of the tree (every chunk under exactly one input node): the CPU's
  last terminal nodes (culled, wholly inside, visible leaves; :attr:`CullResult.terminal_nodes`),
  or the ceiling cut (below). An input node that is visible is traversed on the GPU (stack per
  invocation, plane masking, one level at a time) and the nodes where it stops become next frame's
  input, so with a still camera the input settles on the nodes where a one-level-at-a-time
  traversal from the root stops, those above the ceiling replaced by their descendants on it (the
  CPU steps several levels at a time, so its cut can be finer).
- An input node found outside puts its parent into the next input only when that parent is
  outside too (one more box test); otherwise the parent would be re-traversed and the node
  re-emitted on alternate frames. A second pass drops next-input nodes that have an ancestor in
  it, and duplicates, so the next input is again a cut.
- The result is exact (the same chunks as :func:`node.culling.bvh.cull`, up to float32
  rounding on planes and boxes), not a temporal approximation.
- No invocation may loop long: llvmpipe (Mesa 22.3) silently ends a shader loop after 32768
  iterations, which truncated root-down traversals of ~29k-chunk trees and left holes. So input
  nodes never rise above a *ceiling* depth (:data:`MAX_SUBTREE_LEVELS` above the deepest level:
  each traversal covers at most 4096 chunks), the first input is that ceiling cut, and a visible
  node writes only its run heads into a command buffer cleared before each pass (one command per
  batch it touches), never a loop over all its chunks.
- Both passes are dispatched indirectly: each node list carries its own dispatch size, counted up
  as entries are appended, so idle invocations are not launched for the whole tree.

Frame tags that mark proposals wrap after 2³² frames (over two years at 60 Hz).
"""

from __future__ import annotations

import moderngl
import numpy as np

from node.culling.bvh import ChunkBVH, range_members

_GROUP = 64
#: An input node's subtree spans at most this many levels (2¹² chunks, 8191 nodes per traversal).
MAX_SUBTREE_LEVELS = 12

_COMMON = """
#version 430
layout(local_size_x = 64) in;
struct Node { vec4 lo; vec4 hi; ivec4 tree; };   // lo.w: depth; tree: left child (-1 leaf), parent, first, end chunk
layout(std430, binding = 0) readonly buffer Nodes { Node nodes[]; };
// A node list headed by its own indirect dispatch size (groups of 64, 1, 1) and its length.
layout(std430, binding = 2) buffer Proposals { uint proposal_groups, proposal_y, proposal_z, proposal_count;
                                               uint proposals[]; };
layout(std430, binding = 3) buffer Marks { uint marks[]; };
uniform uint tag;
"""

_CULL_SOURCE = _COMMON + """
layout(std430, binding = 1) readonly buffer Spans { uvec4 spans[]; };   // chunk: first index, index count, batch end
layout(std430, binding = 4) buffer Commands { uint commands[]; };       // cleared to zero before the pass
layout(std430, binding = 5) readonly buffer Input { uint input_groups, input_y, input_z, input_count;
                                                    uint input_nodes[]; };
uniform vec4 planes[6];
uniform float ceiling_depth;
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

void write_commands(int n) {   // visible node n: one command per batch its chunks touch
    int c = nodes[n].tree.z, end = nodes[n].tree.w;
    while (c < end) {
        int next = min(end, int(spans[c].z));
        commands[5 * c + 0] = spans[next - 1].x + spans[next - 1].y - spans[c].x;
        commands[5 * c + 1] = 1u;
        commands[5 * c + 2] = spans[c].x;
        c = next;
    }
}

void propose(int n) {
    uint slot = atomicAdd(proposal_count, 1u);
    proposals[slot] = uint(n);
    marks[n] = tag;
    if (slot % 64u == 0u) atomicAdd(proposal_groups, 1u);
}

void main() {
    uint gid = gl_GlobalInvocationID.x;
    if (gid >= input_count) return;
    int root = int(input_nodes[gid]);
    uint mask = 63u;
    if (classify(root, mask) == OUTSIDE) {
        int parent = nodes[root].tree.y;
        uint parent_mask = 63u;
        bool climb = parent >= 0 && nodes[root].lo.w > ceiling_depth && classify(parent, parent_mask) == OUTSIDE;
        propose(climb ? parent : root);
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
            if (result != OUTSIDE) write_commands(n);
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
layout(std430, binding = 5) buffer Next { uint next_groups, next_y, next_z, next_count; uint next_nodes[]; };

void main() {
    uint gid = gl_GlobalInvocationID.x;
    if (gid >= proposal_count) return;
    int n = int(proposals[gid]);
    for (int a = nodes[n].tree.y; a >= 0; a = nodes[a].tree.y)
        if (marks[a] == tag) return;
    if (atomicExchange(claims[n], tag) == tag) return;
    uint slot = atomicAdd(next_count, 1u);
    next_nodes[slot] = uint(n);
    if (slot % 64u == 0u) atomicAdd(next_groups, 1u);
}
"""


def _node_list(nodes: np.ndarray) -> bytes:
    """A node list as the shaders read it: (dispatch groups, 1, 1, length) then the node ids."""
    nodes = np.asarray(nodes, dtype=np.int64)
    return np.concatenate(([-(-nodes.size // _GROUP), 1, 1, nodes.size], nodes)).astype(np.uint32).tobytes()


class GpuBvh:
    """A :class:`ChunkBVH` and its chunks' index spans uploaded once (SSBOs), with both shaders.

    ``index_starts``/``index_ends`` (C,) are each chunk's index range in the shared index buffer;
    chunks must be contiguous (chunk i ends where i + 1 starts), as the scene's chunks are.
    ``batch_ends`` (C,): for each chunk, the chunk where its batch (material) ends; a visible node's
    command stops there and the next batch's chunks get their own command, so that each batch's
    slice of the commands can be drawn with its own material (default: one batch).
    ``ceiling`` (K,) int64: the tree's cut at depth ``ceiling_depth`` (nodes there and leaves above),
    the shallowest nodes an input may hold.
    """

    def __init__(self, ctx: moderngl.Context, bvh: ChunkBVH, index_starts: np.ndarray,
                 index_ends: np.ndarray, batch_ends: np.ndarray | None = None) -> None:
        if ctx.version_code < 430:
            raise RuntimeError(f"GPU culling needs GL 4.3 compute shaders, context is {ctx.version_code}")
        starts = np.asarray(index_starts, dtype=np.int64)
        ends = np.asarray(index_ends, dtype=np.int64)
        if starts.size != bvh.chunk_count or np.any(starts[1:] != ends[:-1]):
            raise ValueError("GpuBvh needs one contiguous index range per chunk, in chunk order")
        batch_end = np.full(starts.size, starts.size) if batch_ends is None else np.asarray(batch_ends)
        if batch_end.shape != starts.shape or np.any(batch_end <= np.arange(starts.size)) or \
                np.any(batch_end > starts.size):
            raise ValueError("batch_ends must give, for each chunk, an end chunk after it")
        self.ctx, self.bvh = ctx, bvh
        self.index_starts, self.index_ends = starts, ends
        self.depth = bvh.depth
        self.ceiling_depth = max(0, int(self.depth.max()) - MAX_SUBTREE_LEVELS)
        ceiling = np.flatnonzero((self.depth == self.ceiling_depth) | ((self.depth < self.ceiling_depth) & bvh.is_leaf))
        self.ceiling = ceiling[np.argsort(bvh.first_chunk[ceiling])]
        nodes = np.zeros(bvh.node_count, [("lo", "f4", 4), ("hi", "f4", 4), ("tree", "i4", 4)])
        nodes["lo"][:, :3], nodes["hi"][:, :3] = bvh.lo, bvh.hi
        nodes["lo"][:, 3] = self.depth
        nodes["tree"] = np.stack([bvh.left, bvh.parent, bvh.first_chunk, bvh.end_chunk], axis=1)
        self.nodes = ctx.buffer(nodes.tobytes())
        spans = np.stack([starts, ends - starts, batch_end, np.zeros_like(starts)], axis=1)
        self.spans = ctx.buffer(spans.astype(np.uint32).tobytes())
        self.cull_shader = ctx.compute_shader(_CULL_SOURCE)
        self.cull_shader["ceiling_depth"].value = float(self.ceiling_depth)
        self.settle_shader = ctx.compute_shader(_SETTLE_SOURCE)

    @property
    def chunk_count(self) -> int:
        return self.bvh.chunk_count

    def below_ceiling(self, cut_nodes: np.ndarray) -> np.ndarray:
        """(T',) int64: the cut ``cut_nodes`` with every node above :attr:`ceiling_depth` replaced
        by its descendants in :attr:`ceiling`."""
        nodes = np.asarray(cut_nodes, dtype=np.int64)
        high = (self.depth[nodes] < self.ceiling_depth) & ~self.bvh.is_leaf[nodes]
        ceiling_first = self.bvh.first_chunk[self.ceiling]
        lo = np.searchsorted(ceiling_first, self.bvh.first_chunk[nodes[high]])
        hi = np.searchsorted(ceiling_first, self.bvh.end_chunk[nodes[high]])
        return np.concatenate([nodes[~high], self.ceiling[range_members(lo, hi)]])

    def release(self) -> None:
        for resource in (self.nodes, self.spans, self.cull_shader, self.settle_shader):
            resource.release()


class GpuCuller:
    """One tile slot's temporal-coherence culler: its input cut (ping-pong), marks and commands.

    ``commands`` is a (C, 5) uint32 buffer of DrawElementsIndirectCommand rows, rewritten by every
    :meth:`cull`; draw with ``vao.render_indirect(culler.commands, count=culler.command_count)``.
    ``inputs`` are the two node-list buffers (dispatch groups, 1, 1, length, then node ids) that
    take turns: ``inputs[0]`` holds the cut the next :meth:`cull` starts from. Both passes are
    dispatched indirectly, sized by the node list they read.
    """

    def __init__(self, gpu_bvh: GpuBvh) -> None:
        self.gpu_bvh = gpu_bvh
        ctx, node_total = gpu_bvh.ctx, gpu_bvh.bvh.node_count
        header_and_nodes = bytes(4 * (node_total + 4))
        self.inputs = [ctx.buffer(header_and_nodes), ctx.buffer(header_and_nodes)]
        self._proposals = ctx.buffer(header_and_nodes)
        self._marks = ctx.buffer(bytes(4 * node_total))      # frame tag of the last proposal per node
        self._claims = ctx.buffer(bytes(4 * node_total))     # frame tag of the last settled node
        self.commands = ctx.buffer(bytes(20 * gpu_bvh.chunk_count))
        self._tag = 0
        self.seed(gpu_bvh.ceiling)

    @property
    def command_count(self) -> int:
        return self.gpu_bvh.chunk_count

    def seed(self, cut_nodes: np.ndarray) -> None:
        """Start from ``cut_nodes`` (T,) — a cut of the tree, e.g. the CPU's terminal nodes (nodes
        above the ceiling are replaced by their descendants on it)."""
        nodes = np.asarray(cut_nodes, dtype=np.int64)
        bvh = self.gpu_bvh.bvh
        covered = np.sort(range_members(bvh.first_chunk[nodes], bvh.end_chunk[nodes]))
        if not np.array_equal(covered, np.arange(bvh.chunk_count)):
            raise ValueError("seed nodes must be a cut of the tree: every chunk under exactly one of them")
        self.inputs[0].write(_node_list(self.gpu_bvh.below_ceiling(nodes)))

    def cull(self, planes: np.ndarray) -> None:
        """Cull against ``planes`` (6, 4) world space; rewrites :attr:`commands` on the GPU."""
        gpu, ctx = self.gpu_bvh, self.gpu_bvh.ctx
        self._tag += 1
        empty = _node_list(np.zeros(0, np.int64))
        self._proposals.write(empty)
        self.inputs[1].write(empty)
        self.commands.clear()
        gpu.nodes.bind_to_storage_buffer(0)
        self._proposals.bind_to_storage_buffer(2)
        self._marks.bind_to_storage_buffer(3)
        gpu.spans.bind_to_storage_buffer(1)
        self.commands.bind_to_storage_buffer(4)
        self.inputs[0].bind_to_storage_buffer(5)
        gpu.cull_shader["planes"].write(np.asarray(planes, dtype=np.float32).tobytes())
        gpu.cull_shader["tag"].value = self._tag
        gpu.cull_shader.run_indirect(self.inputs[0])
        ctx.memory_barrier(moderngl.SHADER_STORAGE_BARRIER_BIT | moderngl.COMMAND_BARRIER_BIT)
        self._claims.bind_to_storage_buffer(4)
        self.inputs[1].bind_to_storage_buffer(5)
        gpu.settle_shader["tag"].value = self._tag
        gpu.settle_shader.run_indirect(self._proposals)
        ctx.memory_barrier(moderngl.SHADER_STORAGE_BARRIER_BIT | moderngl.COMMAND_BARRIER_BIT)
        self.inputs.reverse()

    def release(self) -> None:
        for buffer in (*self.inputs, self._proposals, self._marks, self._claims, self.commands):
            buffer.release()
