"""Ingest once, open in seconds (issue 31): how fast a scene file becomes a scene cache entry, how
fast a node opens it again, and what either holds in memory, beside what a user would run instead.

``python -m bench.ingest [--scenes REL,...] [--copies 3,5] [--formats ply,glb] [--scan REL]
[--baseline-max 10000000] [--no-peers] [--json OUT]``

For each input — the real scans under ../shared/scenes (``--scenes``) and models of K×K copies of
``--scan`` laid on a grid by :mod:`bench.big_models` (``--copies``, as one binary PLY and one GLB) —
each figure is measured in a fresh process, so its peak resident memory is its own:

- ``cold``: the ingest a node runs when it meets the file first (:func:`node.scene.ingest.read_scene`
  with an empty cache folder: hash, read, split, normals, pack, write, check); triangles per second;
- ``warm``: opening the entry again as a node does (the digest remembered, the entry checked and
  mapped, every page read once as an upload reads it);
- ``trimesh``: ``trimesh.load(path, process=False)`` alone;
- ``baseline``: trimesh's read plus the preprocessing a node ran before the scene cache (smooth
  normals by per-corner ``bincount``, the centroid-Morton octree by ``argsort``, the first-use vertex
  order, 48-byte interleaved vertices: :mod:`bench.ingest_baseline`), for inputs up to
  ``--baseline-max`` triangles;
- ``pyvista``: ``pyvista.read(path)`` (VTK's reader), when PyVista is installed (``pip install
  pyvista``; ``--no-peers`` skips it).

Ratios (baseline / cold) come from one run, on one machine, in turns.
"""

from __future__ import annotations

import argparse
import json
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from bench.big_models import make_models
from bench.processes import PYTHON, REPO, show_result

SCENES = REPO.parent / "shared" / "scenes"
DEFAULT_SCENES = ("bunny/bun_zipper.ply", "large_scan/stanford_dragon_vrip_res2_202k.ply",
                  "large_scan/threedscans_pan_990k.ply", "multi_object/sd_macross_city_diorama.glb")
DEFAULT_SCAN = "large_scan/threedscans_pan_990k.ply"
KINDS = ("cold", "warm", "trimesh", "baseline", "pyvista")


def measure(kind: str, path: Path, cache: Path) -> dict[str, Any]:
    """In this process: one ``kind`` of :data:`KINDS` on ``path`` (cache folder ``cache``): its
    seconds, triangles and the process's peak resident MB."""
    import trimesh  # every kind's imports before the clock starts: a node has them loaded already

    from bench.ingest_baseline import baseline_ingest
    from node.scene.cache_folder import CacheFolder
    from node.scene.ingest import open_cached, read_scene
    from node.scene.pages import release_pages

    if kind == "pyvista":
        import pyvista
    started = time.perf_counter()
    triangles = 0
    if kind in ("cold", "warm"):
        scene = open_cached(read_scene(str(path), str(path), 192, None, lambda f, m: None, CacheFolder(cache)),
                            str(path))
        assert scene.geometry is not None
        for array in (scene.geometry.vertices, scene.geometry.indices):   # read once, as an upload does
            for first in range(0, len(array), 1 << 22):
                array[first:first + (1 << 22)].tobytes()
                release_pages(array, first, first + (1 << 22))
        triangles = scene.triangle_count
    elif kind == "trimesh":
        loaded = trimesh.load(str(path), force="scene", process=False)
        triangles = sum(len(g.faces) for g in loaded.geometry.values() if hasattr(g, "faces"))
    elif kind == "baseline":
        triangles = baseline_ingest(path)
    elif kind == "pyvista":
        read = pyvista.read(str(path))
        mesh = read.combine() if isinstance(read, pyvista.MultiBlock) else read
        triangles = int(mesh.n_cells)
    seconds = time.perf_counter() - started
    return {"seconds": round(seconds, 3), "triangles": triangles,
            "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)}


def run(kind: str, path: Path, cache: Path) -> dict[str, Any] | None:
    """:func:`measure` in a fresh Python process; None when it failed (its reason printed)."""
    done = subprocess.run([PYTHON, "-m", "bench.ingest", "--measure", kind, "--path", str(path), "--cache", str(cache)],
                          cwd=REPO, capture_output=True, text=True)
    if done.returncode != 0:
        print(f"{kind} of {path.name} failed: {done.stderr.strip().splitlines()[-1:] or done.returncode}",
              file=sys.stderr)
        return None
    result: dict[str, Any] = json.loads(done.stdout.strip().splitlines()[-1])
    return result


def has_pyvista() -> bool:
    return subprocess.run([PYTHON, "-c", "import pyvista"], capture_output=True).returncode == 0


def bench_input(path: Path, kinds: list[str], baseline_max: int) -> dict[str, Any]:
    """Every kind of ``kinds`` on ``path``, cold and warm sharing a fresh cache folder."""
    cache = Path(tempfile.mkdtemp(prefix="tessera-bench-ingest-"))
    try:
        row: dict[str, Any] = {"input": path.name, "mb": round(path.stat().st_size / 1e6, 1)}
        for kind in kinds:
            if kind == "baseline" and row.get("triangles", 0) > baseline_max:
                continue
            result = run(kind, path, cache)
            if result is not None:
                row[kind] = result
                row.setdefault("triangles", result["triangles"])
        return row
    finally:
        shutil.rmtree(cache, ignore_errors=True)


def table(rows: list[dict[str, Any]]) -> str:
    def seconds(row: dict[str, Any], kind: str) -> str:
        return f"{row[kind]['seconds']:.2f}" if kind in row else "-"

    def rss(row: dict[str, Any], kind: str) -> str:
        return f"{row[kind]['peak_rss_mb']:.0f}" if kind in row else "-"

    lines = [f"{'input':40s} {'Mtri':>6s} {'MB':>6s} {'cold s':>7s} {'Mtri/s':>7s} {'warm s':>7s} {'trimesh':>8s} "
             f"{'baseline':>9s} {'base/cold':>9s} {'pyvista':>8s}   peak RSS MB cold/warm/trimesh/base/pyvista"]
    for row in rows:
        rate = row["triangles"] / row["cold"]["seconds"] / 1e6 if "cold" in row else float("nan")
        ratio = row["baseline"]["seconds"] / row["cold"]["seconds"] if "baseline" in row and "cold" in row else None
        lines.append(f"{row['input'][:40]:40s} {row['triangles'] / 1e6:6.2f} {row['mb']:6.0f} "
                     f"{seconds(row, 'cold'):>7s} {rate:7.1f} {seconds(row, 'warm'):>7s} {seconds(row, 'trimesh'):>8s} "
                     f"{seconds(row, 'baseline'):>9s} {'-' if ratio is None else f'{ratio:.1f}x':>9s} "
                     f"{seconds(row, 'pyvista'):>8s}   "
                     + "/".join(rss(row, kind) for kind in ("cold", "warm", "trimesh", "baseline", "pyvista")))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.ingest", description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", default=",".join(DEFAULT_SCENES), help="real scenes under ../shared/scenes")
    parser.add_argument("--copies", default="3,5", help="K of the K x K models to generate ('' for none)")
    parser.add_argument("--formats", default="ply,glb")
    parser.add_argument("--scan", default=DEFAULT_SCAN, help="the scan the generated models copy")
    parser.add_argument("--models-dir", type=Path, default=Path(tempfile.gettempdir()) / "tessera-big-models")
    parser.add_argument("--baseline-max", type=int, default=10_000_000, help="most triangles the baseline runs on")
    parser.add_argument("--no-peers", action="store_true", help="skip PyVista")
    parser.add_argument("--json", type=Path)
    parser.add_argument("--measure", choices=KINDS, help=argparse.SUPPRESS)
    parser.add_argument("--path", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--cache", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.measure:
        print(json.dumps(measure(args.measure, args.path, args.cache)))
        return 0
    inputs = [SCENES / relative for relative in args.scenes.split(",") if relative]
    for copies in (int(k) for k in args.copies.split(",") if k):
        inputs += make_models(SCENES / args.scan, copies, args.models_dir, tuple(args.formats.split(",")))
    kinds = [kind for kind in KINDS if kind != "pyvista" or (not args.no_peers and has_pyvista())]
    rows = []
    for path in inputs:
        rows.append(bench_input(path, kinds, args.baseline_max))
        print(table(rows[-1:]).splitlines()[-1], flush=True)
    show_result(table(rows), {"inputs": rows}, args.json, argv)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
