"""A tile's sub-frustum as six world-space planes (seed 001: each tile culls against its own part of
the frame's view frustum), pushed outward so that culling stays conservative."""

from __future__ import annotations

import numpy as np

from tessera.geometry import Rect

#: Tile planes are pushed outward by this many pixels, so a chunk touching the tile is never culled.
DEFAULT_PAD_PX = 1.0
#: Near/far planes are pushed outward by this much NDC depth (float32 rounding in GL and on the GPU).
DEPTH_SLACK = 1e-5


def frustum_planes_from_matrix(view_proj: np.ndarray, size: tuple[int, int], rect: Rect,
                               pad_px: float = DEFAULT_PAD_PX) -> np.ndarray:
    """(6, 4) float64 world-space planes (a, b, c, d), inside where a·x + b·y + c·z + d ≥ 0, of the
    sub-frustum of full-frame ``view_proj`` (4×4 world→clip) that ``rect`` covers in a ``size`` =
    (width, height) image, pushed outward by ``pad_px`` pixels and :data:`DEPTH_SLACK`, so culling
    stays conservative. Order: left, right, bottom, top, near, far; normals are unit length."""
    width, height = size
    m = np.asarray(view_proj, dtype=np.float64)
    x0 = 2.0 * (rect.x - pad_px) / width - 1.0
    x1 = 2.0 * (rect.x1 + pad_px) / width - 1.0
    y0 = 1.0 - 2.0 * (rect.y1 + pad_px) / height      # pixel rows count down from the top
    y1 = 1.0 - 2.0 * (rect.y - pad_px) / height
    planes = np.stack([m[0] - x0 * m[3], x1 * m[3] - m[0],
                       m[1] - y0 * m[3], y1 * m[3] - m[1],
                       m[2] + (1.0 + DEPTH_SLACK) * m[3], (1.0 + DEPTH_SLACK) * m[3] - m[2]])
    return planes / np.linalg.norm(planes[:, :3], axis=1, keepdims=True)
