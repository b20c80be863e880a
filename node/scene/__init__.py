"""Scene data, no GL and no culling: mesh batches, loading files and built-in scenes, and the
octree chunks every batch is pre-split into (seed 002 §3.4)."""
