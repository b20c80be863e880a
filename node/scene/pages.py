"""Arrays mapped from files (:func:`map_array`), and handing their pages back (:func:`release_pages`)
once they are copied where they are needed: a scene cache's arrays are uploaded to the GL block
by block, and the blocks uploaded leave the node's resident memory (they stay in the OS page cache,
which every node on the host shares) instead of counting twice until the scene is dropped.
"""

from __future__ import annotations

import mmap
from pathlib import Path

import numpy as np


def map_array(path: Path, dtype: np.dtype | str, shape: tuple[int, ...], offset: int = 0) -> np.ndarray:
    """The read-only array of ``dtype`` and ``shape`` at byte ``offset`` of the file at ``path``,
    mapped (nothing read until used). Raises OSError, or ValueError when the file is too short."""
    dtype = np.dtype(dtype)
    count = int(np.prod(shape, dtype=np.int64))
    if count == 0:
        return np.zeros(shape, dtype)
    with path.open("rb") as file:
        mapping = mmap.mmap(file.fileno(), 0, access=mmap.ACCESS_READ)
    if len(mapping) < offset + count * dtype.itemsize:
        mapping.close()
        raise ValueError(f"{path}: {len(mapping)} bytes, {offset + count * dtype.itemsize} needed")
    return np.frombuffer(mapping, dtype, count, offset).reshape(shape)


def _mapping(array: np.ndarray) -> mmap.mmap | None:
    base: object = array
    while isinstance(base, np.ndarray):
        base = base.base
    if isinstance(base, memoryview):
        base = base.obj
    return base if isinstance(base, mmap.mmap) else None


def is_mapped(array: np.ndarray) -> bool:
    """Whether ``array`` is (a view of) an array mapped from a file."""
    return _mapping(array) is not None


def release_pages(array: np.ndarray, first: int, end: int) -> None:
    """Drop from this process's resident memory the whole pages that rows [``first``, ``end``) of
    ``array`` (a view of :func:`map_array`'s, C-contiguous rows) lie on; nothing for other arrays."""
    mapping = _mapping(array)
    if mapping is None or end <= first or mapping.closed:
        return
    start_address = np.frombuffer(mapping, np.uint8, 1).ctypes.data
    row_bytes = array.strides[0] if array.ndim else array.itemsize
    start = array.ctypes.data - start_address + first * row_bytes
    stop = start + (end - first) * row_bytes
    page = mmap.PAGESIZE
    start, stop = -(-start // page) * page, stop // page * page
    if stop > start:
        mapping.madvise(mmap.MADV_DONTNEED, start, stop - start)


def resident_mb() -> float:
    """This process's resident memory now, in MiB (Linux ``/proc/self/statm``; 0 where unavailable)."""
    try:
        with open("/proc/self/statm") as statm:
            return int(statm.read().split()[1]) * mmap.PAGESIZE / (1 << 20)
    except (OSError, ValueError, IndexError):
        return 0.0
