"""Decomposition modes by name, as ``--mode`` takes them."""

from __future__ import annotations

import numpy as np

from tessera.balancers.base import Balancer
from tessera.decomposition.hybrid import Hybrid
from tessera.decomposition.mode import DecompositionMode
from tessera.decomposition.sort_first import SortFirst
from tessera.decomposition.sort_last import SortLast

#: The modes (``--mode``); sort-first is the default.
MODES = (SortFirst.name, Hybrid.name, SortLast.name)


def create_mode(name: str, size: tuple[int, int], balancer: Balancer, background: np.ndarray,
                depth_strip: int) -> DecompositionMode:
    """Mode ``name`` over a ``size`` frame; ValueError names the choices. ``background``: (3,)
    uint8; ``depth_strip``: the hybrid's border strip (px)."""
    if name == Hybrid.name:
        return Hybrid(size, balancer, background, depth_strip)
    if name == SortLast.name:
        return SortLast(size, balancer, background)
    if name == SortFirst.name:
        return SortFirst(size, balancer, background)
    raise ValueError(f"unknown mode {name[:64]!r}; choose one of {list(MODES)}")
