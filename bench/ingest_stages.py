"""Where a cold ingest's time goes (issue 31): one scene file made a scene cache entry in this
process, as :mod:`bench.ingest`'s ``cold`` does, with the wall and CPU seconds of each stage.

``python -m bench.ingest_stages PATH [--digest HEX] [--json OUT]``

Each stage is a function of the ingest timed where it is called (:data:`STAGES`; a stage called
inside another counts in both, one run on a thread of its own is named ``[thread]``; functions this
version of the code lacks are left out, so one command measures an older checkout too). CPU
seconds are the whole process's during the stage (its other threads included), steadier than wall
seconds on a machine others load. ``--digest``: the file's SHA-256 given, so that the hash (read on
a thread beside the read) stays out of the figures.
"""

from __future__ import annotations

import argparse
import functools
import importlib
import resource
import shutil
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from bench.processes import show_result

#: (module, attribute path) of each timed stage.
STAGES = (("node.scene.loading", "read_ply"), ("node.scene.loading", "_drop_nonfinite_faces"),
          ("node.scene.octree", "octree_root"), ("node.scene.octree", "morton_codes"),
          ("node.scene.octree", "sorted_by_code"), ("node.scene.compiled", "sorted_vertices"),
          ("node.scene.compiled", "radix_sort"), ("node.scene.compiled", "sorted_faces"),
          ("node.scene.octree", "_cells"), ("node.scene.compiled", "octree_cells"),
          ("node.scene.octree", "face_pass"), ("node.scene.ingest", "pack"),
          ("node.scene.cache", "build_chunk_bvh"), ("node.scene.cache", "write_arrays"),
          ("node.scene.cache", "_crcs"), ("numpy", "save"), ("node.scene.cache_folder", "CacheFolder.content_hash"))


def _timed(function: Callable[..., Any], name: str, seconds: dict[str, list[float]]) -> Callable[..., Any]:
    @functools.wraps(function)
    def timed(*args: Any, **kwargs: Any) -> Any:
        wall, cpu = time.perf_counter(), time.process_time()
        try:
            return function(*args, **kwargs)
        finally:
            key = name if threading.current_thread() is threading.main_thread() else f"{name}[thread]"
            totals = seconds.setdefault(key, [0.0, 0.0])
            totals[0] += time.perf_counter() - wall
            totals[1] += time.process_time() - cpu
    return timed


def measure(path: Path, digest: str | None) -> dict[str, Any]:
    """One cold ingest of ``path`` into a fresh cache folder: its seconds, triangles, peak MB and stages."""
    import trimesh  # noqa: F401  (loaded before the clock, as bench.ingest does)

    from node.scene.cache_folder import CacheFolder
    from node.scene.ingest import open_cached, read_scene

    seconds: dict[str, list[float]] = {}
    for module_name, attribute in STAGES:
        owner: Any = importlib.import_module(module_name)
        *parents, name = attribute.split(".")
        for parent in parents:
            owner = getattr(owner, parent)
        if hasattr(owner, name):
            setattr(owner, name, _timed(getattr(owner, name), name, seconds))
    cache = Path(tempfile.mkdtemp(prefix="tessera-bench-stages-"))
    try:
        wall, cpu = time.perf_counter(), time.process_time()
        scene = open_cached(read_scene(str(path), str(path), 192, None, lambda f, m: None, CacheFolder(cache),
                                       sha256=digest), str(path))
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    finally:
        shutil.rmtree(cache, ignore_errors=True)
    peak_mb = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
    return {"input": path.name, "triangles": scene.triangle_count, "seconds": round(wall, 3),
            "cpu_seconds": round(cpu, 3), "peak_rss_mb": peak_mb,
            "stages": {name: {"seconds": round(w, 3), "cpu_seconds": round(c, 3)}
                       for name, (w, c) in sorted(seconds.items(), key=lambda item: -item[1][1])}}


def table(result: dict[str, Any]) -> str:
    lines = [f"{result['input']}: {result['triangles'] / 1e6:.2f}M triangles in {result['seconds']:.2f} s "
             f"({result['triangles'] / result['seconds'] / 1e6:.2f}M/s), {result['cpu_seconds']:.2f} CPU-s, "
             f"peak {result['peak_rss_mb']} MB", f"  {'stage':32s} {'wall s':>7s} {'CPU s':>7s}"]
    lines += [f"  {name:32s} {stage['seconds']:7.2f} {stage['cpu_seconds']:7.2f}"
              for name, stage in result["stages"].items()]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.ingest_stages", description=__doc__.split("\n\n")[0])
    parser.add_argument("path", type=Path)
    parser.add_argument("--digest", help="the file's SHA-256, so that it is not hashed")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    result = measure(args.path, args.digest)
    show_result(table(result), result, args.json, argv)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
