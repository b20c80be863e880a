"""Per-tile frustum culling (seed 001 §6): the tree over a scene's chunks and its CPU traversal,
GPU culling with temporal coherence, the hybrid CPU↔GPU switch, and the per-tile culler the
renderer draws with."""
