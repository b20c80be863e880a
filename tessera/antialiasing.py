"""The resolve filters of frames drawn with one or more samples per pixel (issues 20, 37): how the
frame comes closer to the pixel's area — what the 4×4 supersampled reference averages — than one
sample at its centre.

A frame drawn at one sample per pixel holds each pixel's centre; the reference (and a multisampled
pixel) holds the mean over the pixel's square. :func:`resolve_filter` estimates that mean from the
centre samples of the pixel and its neighbours: the separable kernel [1, 6, 1] / 8 along x and along
y (weights 36/64 on the pixel, 6/64 on each side neighbour, 1/64 on each corner), integers, rounded
half up. It is close to the least-squares 3×3 kernel from the one-sample frames of the benchmark's
scenes to their 4×4 supersampled references, and as good (``python -m bench.picture``; figures in the
design notes). A linear filter only spreads what the samples saw: geometry thinner than a pixel stays
as aliased as it was drawn, which more samples cure.

**Sample grids.** A frame drawn over a viewport ``kx`` × ``ky`` times as large with the same
projection holds, in each pixel, a ``kx`` × ``ky`` ordered grid of samples (block (i, j) of the
large frame is pixel (i, j)'s): one draw, any count. :func:`resolve_grid` averages each pixel's
block and, for the small grids, filters the sums: the pair (2 × 1, ``--msaa auto`` on llvmpipe:
samples ¼ pixel left and right of the centre) by [1, 14, 1] / 16 along x (the pair already spans the
pixel's width) and [1, 6, 1] / 8 along y; 2 × 2 by [1, 14, 1] / 16 along both; 3 × 3 and 4 × 4 not at
all (nine samples already span the pixel). Which grid a frame of a given size gets is the node's choice
(:func:`node.gl.shading.resolve_antialiasing`).

Tiles stay seamless: a pixel's result depends on its 3×3 neighbourhood only (its own block when not
filtered), so a filtered tile is drawn with a guard band of :data:`GUARD` pixel around it
(:func:`guarded`), and outside the frame the nearest frame pixel stands in (clamp to edge) — the
same neighbourhood whichever tile a pixel lies in. Pure: numpy arrays in, arrays out.
"""

from __future__ import annotations

import functools

import numpy as np

from tessera.geometry import Rect

#: Pixels each side of a tile that the filter reads.
GUARD = 1
#: Texture LOD bias of filtered frames: textures read one level finer, as a still of 4 samples reads
#: them (the filter blurs a little; finer texels make up for it). Finer still gains little more and one
#: sample per pixel would shimmer in motion (see the design notes).
FILTERED_LOD_BIAS = -1.0


def guarded(rect: Rect, size: tuple[int, int]) -> Rect:
    """``rect`` grown by :data:`GUARD` pixels on each side, clipped to the ``size`` = (w, h) frame."""
    x, y = max(rect.x - GUARD, 0), max(rect.y - GUARD, 0)
    return Rect(x, y, min(rect.x1 + GUARD, size[0]) - x, min(rect.y1 + GUARD, size[1]) - y)


def resolve_filter(pixels: np.ndarray, rect: Rect, drawn: Rect) -> np.ndarray:
    """(rect.h, rect.w, 3) uint8: ``rect`` of the frame filtered, from ``pixels`` (drawn.h, drawn.w, 3)
    uint8, the frame's ``drawn`` = :func:`guarded` (``rect``) region; where the guard band was
    clipped by the frame's edge, the edge pixels stand in."""
    return resolve_grid(pixels, rect, drawn, (1, 1))


def resolve_pair_filter(pixels: np.ndarray, rect: Rect, drawn: Rect) -> np.ndarray:
    """(rect.h, rect.w, 3) uint8: ``rect`` of the frame drawn with two samples per pixel, ¼ pixel
    left and right of its centre, from ``pixels`` (drawn.h, 2·drawn.w, 3) uint8: the ``drawn`` =
    :func:`guarded` (``rect``) region of a frame drawn twice as wide: :func:`resolve_grid` of the
    (2, 1) grid."""
    return resolve_grid(pixels, rect, drawn, (2, 1))


#: The filter of each sample grid (kx, ky) that has one: the centre weights of [1, c, 1] along x and y.
GRID_FILTERS: dict[tuple[int, int], tuple[int, int]] = {(1, 1): (6, 6), (2, 1): (14, 6), (2, 2): (14, 14)}


def resolve_grid(pixels: np.ndarray, rect: Rect, drawn: Rect, grid: tuple[int, int],
                 filtered: bool = True) -> np.ndarray:
    """(rect.h, rect.w, 3) uint8: ``rect`` of the frame drawn with the ``grid`` = (kx, ky) of samples
    per pixel, from ``pixels`` (ky·drawn.h, kx·drawn.w, 3) uint8, the ``drawn`` region of a frame
    drawn kx × ky times as large (``drawn`` = :func:`guarded` (``rect``) for a filtered grid,
    ``rect`` otherwise): each pixel's samples summed, then filtered (:data:`GRID_FILTERS`; not
    with ``filtered`` False: a still's sample, averaged only) or not, divided and rounded half up;
    where a guard band was clipped by the frame's edge, the edge pixels stand in."""
    kx, ky = grid
    if pixels.shape[:2] != (ky * drawn.h, kx * drawn.w):
        raise ValueError(f"pixels are {pixels.shape[1]}x{pixels.shape[0]}, the drawn region {kx}x{ky} as large "
                         f"{kx * drawn.w}x{ky * drawn.h} (twice as wide for the pair)")
    count = kx * ky
    if grid not in GRID_FILTERS or not filtered:
        if drawn != rect:
            raise ValueError(f"an unfiltered grid's drawn region {drawn.as_list()} must be its rect {rect.as_list()}")
        return _rounded_mean(count)[_block_sums(pixels, grid, np.uint16)]
    centre_x, centre_y = GRID_FILTERS[grid]
    total = count * (centre_x + 2) * (centre_y + 2)
    shift = total.bit_length() - 1
    if total != 1 << shift:
        raise ValueError(f"grid {grid}'s filter weights sum to {total}, not a power of two")
    sums = _block_sums(pixels, grid, np.uint16 if 255 * total < 1 << 16 else np.uint32)
    return _separable(sums, rect, drawn, centre_x, centre_y, shift)


def _block_sums(pixels: np.ndarray, grid: tuple[int, int], dtype: type) -> np.ndarray:
    """(h, w, 3) of ``dtype``: each kx × ky block of ``pixels`` (ky·h, kx·w, 3) summed (one strided
    add per sample: 4x faster than numpy's sum over reshaped axes on a 720p pair)."""
    kx, ky = grid
    sums: np.ndarray = pixels[0::ky, 0::kx].astype(dtype)
    for j in range(ky):
        for i in range(kx):
            if i or j:
                sums += pixels[j::ky, i::kx]
    return sums


@functools.lru_cache(maxsize=8)
def _rounded_mean(count: int) -> np.ndarray:
    """(255·count + 1,) uint8: a sum of ``count`` 8-bit samples → their mean rounded half up."""
    sums = np.arange(255 * count + 1, dtype=np.int64)
    return ((2 * sums + count) // (2 * count)).astype(np.uint8)


def _separable(values: np.ndarray, rect: Rect, drawn: Rect, centre_x: int, centre_y: int, shift: int) -> np.ndarray:
    """(rect.h, rect.w, 3) uint8: ``values`` (drawn.h, drawn.w, 3) uint16 or uint32 of the ``drawn``
    region filtered by [1, ``centre_x``, 1] along x and [1, ``centre_y``, 1] along y (edge pixels
    standing in beyond a clipped guard band), divided by 2**``shift`` rounded half up; the sums stay
    inside ``values``' type."""
    pad = ((GUARD - (rect.y - drawn.y), GUARD - (drawn.y1 - rect.y1)),
           (GUARD - (rect.x - drawn.x), GUARD - (drawn.x1 - rect.x1)), (0, 0))
    if any(before < 0 or after < 0 for before, after in pad):
        raise ValueError(f"drawn region {drawn.as_list()} is not rect {rect.as_list()} with its guard band")
    wide = np.pad(values, pad, mode="edge")
    kind = values.dtype.type
    rows = wide[:, 1:-1] * kind(centre_x)
    rows += wide[:, :-2]
    rows += wide[:, 2:]
    out = rows[1:-1] * kind(centre_y)
    out += rows[:-2]
    out += rows[2:]
    out += kind(1 << (shift - 1))
    out >>= kind(shift)
    return out.astype(np.uint8)
