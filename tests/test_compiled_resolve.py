"""The compiled resolve of filtered sample grids (:mod:`node.gl.resolve`): the same pixels, bit for
bit, as the numpy passes of :func:`tessera.antialiasing.resolve_grid`, for every filtered grid, tiles
anywhere in the frame (their guard band clipped at its edges), and loaded in the background on
first use."""

from __future__ import annotations

import numpy as np
import pytest

from node.gl import resolve as compiled
from tessera.antialiasing import GRID_FILTERS, guarded, resolve_grid
from tessera.geometry import Rect

pytest.importorskip("numba")

SIZE = (53, 37)


def tiles(rng: np.random.Generator, count: int) -> list[Rect]:
    """``count`` random tiles of a ``SIZE`` frame, the four corners' among them."""
    out = [Rect(0, 0, *SIZE), Rect(0, 0, 1, 1), Rect(SIZE[0] - 1, SIZE[1] - 1, 1, 1), Rect(0, 20, SIZE[0], 17)]
    while len(out) < count:
        x, y = int(rng.integers(0, SIZE[0])), int(rng.integers(0, SIZE[1]))
        out.append(Rect(x, y, int(rng.integers(1, SIZE[0] - x + 1)), int(rng.integers(1, SIZE[1] - y + 1))))
    return out


@pytest.mark.parametrize("grid", sorted(GRID_FILTERS))
def test_the_compiled_pass_gives_the_numpy_passes_pixels(grid: tuple[int, int]) -> None:
    kernel = compiled.load_kernel()
    rng = np.random.default_rng(sum(grid))
    kx, ky = grid
    for rect in tiles(rng, 60):
        drawn = guarded(rect, SIZE)
        samples = rng.integers(0, 256, (ky * drawn.h, kx * drawn.w, 3), dtype=np.uint8)
        samples[: ky * drawn.h // 2, : kx * drawn.w // 3] = 255   # the largest sums too
        expected = resolve_grid(samples, rect, drawn, grid)
        assert np.array_equal(compiled.compiled_resolve(kernel, samples, rect, drawn, grid), expected), rect


def test_the_compiled_pass_refuses_what_the_numpy_passes_refuse() -> None:
    kernel = compiled.load_kernel()
    with pytest.raises(ValueError, match="twice as wide"):
        compiled.compiled_resolve(kernel, np.zeros((4, 9, 3), np.uint8), Rect(0, 0, 5, 4), Rect(0, 0, 5, 4), (2, 1))
    with pytest.raises(ValueError, match="guard band"):
        compiled.compiled_resolve(kernel, np.zeros((5, 14, 3), np.uint8), Rect(2, 0, 5, 5), Rect(0, 0, 7, 5), (2, 1))


def test_resolve_loads_the_kernel_on_first_use_and_then_takes_it(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(compiled, "_kernel", None)
    monkeypatch.setattr(compiled, "_loading", None)
    rng = np.random.default_rng(7)
    rect, drawn = Rect(3, 2, 20, 11), guarded(Rect(3, 2, 20, 11), SIZE)
    samples = rng.integers(0, 256, (drawn.h, 2 * drawn.w, 3), dtype=np.uint8)
    expected = resolve_grid(samples, rect, drawn, (2, 1))
    assert np.array_equal(compiled.resolve(samples, rect, drawn, (2, 1)), expected)   # numpy meanwhile
    assert compiled._loading is not None
    compiled._loading.join(timeout=120)
    assert compiled._kernel   # loaded: the next frames take it
    calls: list[int] = []
    kernel = compiled._kernel
    monkeypatch.setattr(compiled, "_kernel", lambda *args: calls.append(1) or kernel(*args))
    assert np.array_equal(compiled.resolve(samples, rect, drawn, (2, 1)), expected)
    assert calls == [1]
    grid_3x3 = rng.integers(0, 256, (3 * 4, 3 * 5, 3), dtype=np.uint8)   # unfiltered grids: numpy's mean
    assert np.array_equal(compiled.resolve(grid_3x3, Rect(0, 0, 5, 4), Rect(0, 0, 5, 4), (3, 3), False),
                          resolve_grid(grid_3x3, Rect(0, 0, 5, 4), Rect(0, 0, 5, 4), (3, 3), False))
    assert calls == [1]


def test_the_image_keeps_numbas_kernels_in_the_nodes_scene_cache_volume(tmp_path) -> None:
    """The root filesystem is read-only: the Dockerfile points numba's cache into the folder a node
    container mounts its scene cache volume on, where the folder's trimming leaves it alone."""
    import shlex
    from pathlib import Path

    import yaml

    from node.scene.cache_folder import CacheFolder

    repo = Path(__file__).resolve().parents[1]
    lines = (repo / "Dockerfile").read_text().replace("\\\n", " ").splitlines()
    env = dict(word.split("=", 1) for line in lines if line.startswith("ENV ") for word in shlex.split(line[4:]))
    cache = Path(env["NUMBA_CACHE_DIR"])
    node = yaml.safe_load((repo / "docker-compose.yml").read_text())["services"]["node"]
    volume = Path(next(mount["target"] for mount in node["volumes"] if mount.get("source") == "scene-cache"))
    assert cache.parent == volume and Path(node["environment"]["TESSERA_SCENE_CACHE_DIR"]) == volume
    kept = tmp_path / cache.name / "node" / "gl"
    kept.mkdir(parents=True)
    (kept / "resolve.filtered_grid-1.py311.nbi").write_bytes(b"x" * 4096)
    folder = CacheFolder(tmp_path, limit_bytes=1)
    assert folder.usage() == [] and folder.trim() == [] and kept.is_dir()


def test_a_second_process_reads_the_kernel_from_numbas_cache(tmp_path) -> None:
    """Compiled once per cache folder, not once per process (a node's start paid ~1 s of CPU for it):
    the kernel holds no compiled function in its closure, which numba's cache cannot key."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    probe = ("import numpy as np\n"
             "from node.gl import resolve\n"
             "kernel = resolve.load_kernel()\n"
             "kernel(np.zeros((3, 6, 3), np.uint8), np.empty((1, 1, 3), np.uint8), 2, 1, 14, 6, 8, 1, 1)\n"
             "print(sum(kernel.stats.cache_hits.values()), sum(kernel.stats.cache_misses.values()))\n")
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba"),
           "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    runs = [subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True, timeout=120,
                           check=True) for _ in range(2)]
    (hits_first, misses_first), (hits_second, misses_second) = (tuple(map(int, run.stdout.split())) for run in runs)
    assert (hits_first, misses_first) == (0, 1)
    assert (hits_second, misses_second) == (1, 0)
