"""Eye-dome lighting (issue 36; Boucheny's EDL as Potree draws it): unshaded points made readable by
a screen-space pass over depth alone. A pixel is darkened by how much nearer its 8 neighbours are,
in log depth (so the effect does not depend on the distance), and a background pixel next to a point
turns dark (the silhouettes' outline). Pure numpy, the same on a render node (per tile) and on the
coordinator (after a sort-last merge), so a frame shaded there equals one shaded whole.

A pixel's shade reads its neighbours one pixel away: a tile is shaded from the tile grown by
:data:`GUARD_PX` (drawn with the full-frame camera: the same depths as the whole frame's there) and
cropped, so tiles join without seams (as :mod:`tessera.antialiasing`'s filter does).
"""

from __future__ import annotations

import numpy as np

from tessera.geometry import Rect

#: Pixels a pixel's shade reads around it.
GUARD_PX = 1
#: Potree's defaults: the response's scale and strength.
EDL_SCALE = 300.0
DEFAULT_EDL_STRENGTH = 1.0
#: Window depth of a pixel nothing was drawn on.
FAR_DEPTH = 1.0

_NEIGHBOURS = ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1))


def log_depth(depth: np.ndarray, near: float, far: float) -> np.ndarray:
    """(h, w) float32 log2 of the eye-space distance of window ``depth`` (h, w) float32 ([0, 1],
    GL's default depth range, a perspective projection between ``near`` and ``far``); +inf where
    nothing was drawn (depth 1)."""
    level = np.multiply(depth, np.float32(2.0), dtype=np.float32)    # in place from here: no temporaries
    level -= np.float32(1.0)
    level *= np.float32(far - near)
    np.subtract(np.float32(far + near), level, out=level)
    with np.errstate(divide="ignore"):
        np.divide(np.float32(2.0 * near * far), level, out=level)
        np.log2(level, out=level)
    level[depth >= FAR_DEPTH] = np.inf
    return level


def shade(color: np.ndarray, level: np.ndarray, strength: float = DEFAULT_EDL_STRENGTH) -> np.ndarray:
    """(h, w, 3) uint8 ``color`` shaded by the EDL of ``level`` (h + 2, w + 2) float32 (log depth,
    +inf where nothing was drawn; its border is only read). A pixel's response is the mean over its 8
    neighbours of how much nearer they are (log2), each step ignored where the neighbour is empty;
    a background pixel next to a point has an infinite one (the outline); the colour is scaled by
    exp(−response · :data:`EDL_SCALE` · strength), in steps of 1/256 (integers: the same everywhere)."""
    centre = level[1:-1, 1:-1]
    response = np.zeros(centre.shape, np.float32)
    step = np.empty(centre.shape, np.float32)
    height, width = centre.shape
    with np.errstate(invalid="ignore"):
        for dy, dx in _NEIGHBOURS:
            np.subtract(centre, level[1 + dy:1 + dy + height, 1 + dx:1 + dx + width], out=step)
            np.fmax(step, np.float32(0.0), out=step)      # nan (both empty) counts as 0
            response += step
    response *= np.float32(-EDL_SCALE * strength / len(_NEIGHBOURS) / np.log(2.0))
    np.exp2(response, out=response)
    response *= np.float32(256.0)
    weight = np.rint(response, out=response).astype(np.uint16)
    shaded = color.astype(np.uint16)
    shaded *= weight[..., None]
    shaded += 128
    shaded >>= 8
    return shaded.astype(np.uint8)


def eye_dome(color: np.ndarray, depth: np.ndarray, near: float, far: float,
             strength: float = DEFAULT_EDL_STRENGTH) -> np.ndarray:
    """(h, w, 3) uint8: a whole frame's ``color`` (h, w, 3) uint8 shaded by the EDL of its window
    ``depth`` (h, w) float32 (nothing drawn beyond its edges)."""
    level = np.full((depth.shape[0] + 2, depth.shape[1] + 2), np.inf, np.float32)
    level[1:-1, 1:-1] = log_depth(depth, near, far)
    return shade(color, level, strength)


def guarded_rect(rect: Rect, size: tuple[int, int]) -> Rect:
    """``rect`` grown by :data:`GUARD_PX` on every side, clipped to the ``size`` frame: what is drawn
    to shade it."""
    x0, y0 = max(rect.x - GUARD_PX, 0), max(rect.y - GUARD_PX, 0)
    x1, y1 = min(rect.x1 + GUARD_PX, size[0]), min(rect.y1 + GUARD_PX, size[1])
    return Rect(x0, y0, x1 - x0, y1 - y0)


def shade_region(color: np.ndarray, depth: np.ndarray, drawn: Rect, rect: Rect, near: float, far: float,
                 strength: float = DEFAULT_EDL_STRENGTH) -> np.ndarray:
    """(rect.h, rect.w, 3) uint8: ``rect`` of a frame shaded by EDL, from ``color`` (h, w, 3) and
    window ``depth`` (h, w) of ``drawn`` (:func:`guarded_rect` of it); beyond the frame's edge
    nothing is drawn."""
    top, left = rect.y - drawn.y, rect.x - drawn.x
    if not (0 <= top <= GUARD_PX and 0 <= left <= GUARD_PX and drawn.x1 >= rect.x1 and drawn.y1 >= rect.y1):
        raise ValueError(f"drawn {drawn.as_list()} does not hold {rect.as_list()} and its guard band")
    level = np.full((rect.h + 2 * GUARD_PX, rect.w + 2 * GUARD_PX), np.inf, np.float32)
    y0, x0 = GUARD_PX - top, GUARD_PX - left
    height, width = min(drawn.h, level.shape[0] - y0), min(drawn.w, level.shape[1] - x0)
    level[y0:y0 + height, x0:x0 + width] = log_depth(depth[:height, :width], near, far)
    return shade(color[top:top + rect.h, left:left + rect.w], level, strength)
