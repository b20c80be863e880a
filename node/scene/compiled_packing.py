"""The vertex packing's compiled pass (issue 31), numba's: a vertex's position and float16 normal
written as the interleaved vertex array holds them, in one pass (numpy assigns each field apart and
converts the normals in another; numba has no float16, so the rounding is numpy's own algorithm on
the bits). Imported by :mod:`node.scene.compiled` only where numba is installed; the kernels are
module-level functions so that numba's cache keeps them (a kernel calling a closure is compiled
again in every process). No GL here."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numba
import numpy as np


def _jit(function: Callable[..., Any]) -> Any:
    """``function`` compiled, kept in numba's cache where there is a folder for it."""
    try:
        return numba.njit(cache=True, nogil=True)(function)
    except RuntimeError:   # no folder to cache it in (a read-only install, no home): compiled each time
        return numba.njit(nogil=True)(function)


@_jit
def half_bits(bits: np.uint32) -> np.uint16:
    """The float16 nearest (ties to even) to the float32 of ``bits``, as numpy rounds it
    (npy_floatbits_to_halfbits): subnormals, overflow to infinity, NaN kept a NaN."""
    sign = (bits >> np.uint32(16)) & np.uint32(0x8000)
    exponent = bits & np.uint32(0x7F800000)
    if exponent >= np.uint32(0x47800000):                       # overflow, infinity or NaN
        fraction = bits & np.uint32(0x007FFFFF)
        if exponent == np.uint32(0x7F800000) and fraction != 0:
            nan = np.uint32(0x7C00) + (fraction >> np.uint32(13))
            return np.uint16(sign + (nan + np.uint32(1) if nan == np.uint32(0x7C00) else nan))
        return np.uint16(sign + np.uint32(0x7C00))
    if exponent <= np.uint32(0x38000000):                       # a subnormal half, or zero
        if exponent < np.uint32(0x33000000):
            return np.uint16(sign)
        significand = (np.uint32(0x00800000) + (bits & np.uint32(0x007FFFFF))) >> (
            np.uint32(113) - (exponent >> np.uint32(23)))
        if (significand & np.uint32(0x3FFF)) != np.uint32(0x1000) or (bits & np.uint32(0x7FF)) != 0:
            significand += np.uint32(0x1000)
        return np.uint16(sign + (significand >> np.uint32(13)))
    significand = bits & np.uint32(0x007FFFFF)
    if (significand & np.uint32(0x3FFF)) != np.uint32(0x1000):
        significand += np.uint32(0x1000)
    return np.uint16(sign + ((exponent - np.uint32(0x38000000)) >> np.uint32(13)) + (significand >> np.uint32(13)))

@_jit
def halves(bits: np.ndarray, out: np.ndarray) -> None:
    for item in range(bits.size):
        out[item] = half_bits(bits[item])

@_jit
def interleave(position_bits: np.ndarray, normal_bits: np.ndarray, words: np.ndarray) -> None:
    """Rows of ``words`` (N, W) uint32 (vertices of a stride of W words): position (3 words) then the
    normal as three float16 (and two bytes of zero padding), from float32 bits (N, 3) uint32 each."""
    for vertex in range(position_bits.shape[0]):
        words[vertex, 0] = position_bits[vertex, 0]
        words[vertex, 1] = position_bits[vertex, 1]
        words[vertex, 2] = position_bits[vertex, 2]
        words[vertex, 3] = np.uint32(half_bits(normal_bits[vertex, 0])) | (
            np.uint32(half_bits(normal_bits[vertex, 1])) << np.uint32(16))
        words[vertex, 4] = np.uint32(half_bits(normal_bits[vertex, 2]))
