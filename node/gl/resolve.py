"""A frame's filtered sample grid resolved in one compiled pass (issue 32): the same pixels, bit for
bit, as :func:`tessera.antialiasing.resolve_grid`, whose numpy passes (a dozen over the frame's sums:
the block sums, the guard band's padding, the filter along x and along y, the rounding) took about
11 ms of CPU a 1280x720 moving frame drawn as the pair, a twentieth of what the 24.8M-triangle model's
three nodes spent on it.

The kernel is compiled by numba, loaded the first time a node resolves a frame, in a thread of its
own (importing numba and loading the kernel cost about 0.2 s of CPU, compiling it once about 2 s;
``cache=True`` keeps it), so no frame waits for it: until it is ready, and where numba is missing,
frames take the numpy passes. Grids without a filter (3x3, 4x4: the mean alone) always do.
"""

from __future__ import annotations

import threading
from typing import Any

import numpy as np

from tessera.antialiasing import GRID_FILTERS, GUARD, resolve_grid
from tessera.geometry import Rect

_lock = threading.Lock()
#: The compiled kernel once loaded; False where numba is missing or failed; None: not asked for yet.
_kernel: Any = None
_loading: threading.Thread | None = None
#: The compiled row sums :func:`_build`'s kernel calls (set there).
_block_sums: Any = None


def resolve(pixels: np.ndarray, rect: Rect, drawn: Rect, grid: tuple[int, int], filtered: bool = True) -> np.ndarray:
    """:func:`tessera.antialiasing.resolve_grid` (same arguments, the same (rect.h, rect.w, 3) uint8),
    by the compiled kernel when it is loaded and the grid is filtered; asks for it the first time."""
    kernel = _kernel if _kernel is not None else _start_loading()
    if not kernel or not filtered or grid not in GRID_FILTERS:
        return resolve_grid(pixels, rect, drawn, grid, filtered)
    return compiled_resolve(kernel, pixels, rect, drawn, grid)


def compiled_resolve(kernel: Any, pixels: np.ndarray, rect: Rect, drawn: Rect, grid: tuple[int, int]) -> np.ndarray:
    """The filtered ``grid`` resolved by ``kernel`` (:func:`load_kernel`); arguments checked as
    :func:`tessera.antialiasing.resolve_grid` checks them."""
    kx, ky = grid
    if pixels.shape[:2] != (ky * drawn.h, kx * drawn.w) or pixels.dtype != np.uint8 or pixels.shape[2] != 3:
        return resolve_grid(pixels, rect, drawn, grid)   # raises its error
    left, top = rect.x - drawn.x, rect.y - drawn.y
    if not (0 <= left <= GUARD and 0 <= top <= GUARD and 0 <= drawn.x1 - rect.x1 <= GUARD
            and 0 <= drawn.y1 - rect.y1 <= GUARD):
        return resolve_grid(pixels, rect, drawn, grid)   # raises its error
    centre_x, centre_y = GRID_FILTERS[grid]
    shift = (kx * ky * (centre_x + 2) * (centre_y + 2)).bit_length() - 1
    out = np.empty((rect.h, rect.w, 3), np.uint8)
    kernel(pixels, out, kx, ky, centre_x, centre_y, shift, left, top)
    return out


def _start_loading() -> Any:
    """The kernel if loaded (False: it cannot be); else start loading it in a thread, once: None."""
    global _loading
    with _lock:
        if _loading is None:
            _loading = threading.Thread(target=_load, name="tessera-resolve-compile", daemon=True)
            _loading.start()
    return _kernel


def _load() -> None:
    global _kernel
    try:
        kernel = load_kernel()
        warm = np.zeros((3, 6, 3), np.uint8)
        kernel(warm, np.empty((1, 1, 3), np.uint8), 2, 1, 14, 6, 8, 1, 1)   # compiled (or read from its cache) now
    except Exception:  # numba missing, or it cannot compile here: the numpy passes serve
        kernel = False
    _kernel = kernel


def load_kernel() -> Any:
    """The compiled kernel ``kernel(pixels, out, kx, ky, centre_x, centre_y, shift, left, top)``:
    ``out`` (h, w, 3) uint8 the pixels of the region of the ``pixels`` (ky·H, kx·W, 3) uint8 samples
    of an H × W region whose pixel (``left`` + i, ``top`` + j) is out's (i, j): each pixel's kx × ky
    samples summed, filtered by [1, ``centre_x``, 1] along x and [1, ``centre_y``, 1] along y (pixels
    beyond the region clamped to its edge), divided by 2**``shift`` rounded half up. Raises
    ImportError without numba."""
    import numba

    try:
        return _build(numba.njit(cache=True, nogil=True))
    except RuntimeError:   # no folder to cache it in (a read-only install, no home): compiled each time
        return _build(numba.njit(nogil=True))


def _build(jit: Any) -> Any:
    global _block_sums

    def block_sums(pixels: np.ndarray, row: np.ndarray, sy: int, kx: int, ky: int, left: int, width: int) -> None:
        """``row`` ((w + 2)·3,) int32: the sample sums of the pixels of region row ``sy`` / ky that out's
        row reads, from column ``left`` − 1 to ``left`` + w (clamped to the region's ``width``)."""
        for q in range(row.size // 3):
            sx = min(max(left + q - 1, 0), width - 1) * kx
            if kx == 2 and ky == 1:   # the pair, unrolled: the moving frame's grid at 720p and up
                src = pixels[sy]
                row[3 * q] = np.int32(src[sx, 0]) + np.int32(src[sx + 1, 0])
                row[3 * q + 1] = np.int32(src[sx, 1]) + np.int32(src[sx + 1, 1])
                row[3 * q + 2] = np.int32(src[sx, 2]) + np.int32(src[sx + 1, 2])
                continue
            a0, a1, a2 = np.int32(0), np.int32(0), np.int32(0)
            for j in range(ky):
                src = pixels[sy + j]
                for i in range(kx):
                    a0 += np.int32(src[sx + i, 0])
                    a1 += np.int32(src[sx + i, 1])
                    a2 += np.int32(src[sx + i, 2])
            row[3 * q], row[3 * q + 1], row[3 * q + 2] = a0, a1, a2

    # A module global, not a closure variable: numba's cache keys a kernel by its closure, and a
    # compiled function held there made the kernel compile again in every process.
    _block_sums = jit(block_sums)

    @jit
    def filtered_grid(pixels: np.ndarray, out: np.ndarray, kx: int, ky: int, centre_x: int, centre_y: int,
                      shift: int, left: int, top: int) -> None:
        height, width = pixels.shape[0] // ky, pixels.shape[1] // kx
        h, w = out.shape[0], out.shape[1]
        # The sums of three rows at a time (those out's row reads), kept in cache, not the frame's.
        ring = np.empty((3, (w + 2) * 3), np.int32)
        for r in range(2):
            _block_sums(pixels, ring[r], min(max(top + r - 1, 0), height - 1) * ky, kx, ky, left, width)
        cx, cy, half, bits = np.int32(centre_x), np.int32(centre_y), np.int32(1 << (shift - 1)), np.int32(shift)
        flat = out.reshape(h, w * 3)
        for y in range(h):
            _block_sums(pixels, ring[(y + 2) % 3], min(max(top + y + 1, 0), height - 1) * ky, kx, ky, left, width)
            above, here, below, line = ring[y % 3], ring[(y + 1) % 3], ring[(y + 2) % 3], flat[y]
            for k in range(w * 3):
                total = (above[k] + cx * above[k + 3] + above[k + 6]
                         + cy * (here[k] + cx * here[k + 3] + here[k + 6])
                         + below[k] + cx * below[k + 3] + below[k + 6])
                line[k] = np.uint8((total + half) >> bits)

    return filtered_grid
