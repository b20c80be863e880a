"""Decomposition modes (seed 000 §4.4): sort-first tiles, the hybrid's chunk ownership, sort-last
data partitions and shares."""
