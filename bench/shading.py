"""Shading cost (issue 20): the frame time of this tree's shader against another tree's, on the scans.

``python -m bench.shading [--tree REV] [--baseline REV …] [--scene S …] [--size 1280x720] [--frames 7]
[--rounds 2] [--msaa 1] [--json OUT]``

Each tree — this working tree (or the ``--tree`` revision) and each ``--baseline`` revision (default
:data:`LAMBERT_REVISION`, the tree before physically based shading, whose shader was one headlight
with Lambert diffuse), a revision's ``node`` and ``tessera`` packages taken out with ``git archive``
— renders every scene in a process of its own: the scene loaded, a
:class:`node.gl.renderer.TileRenderer` with its defaults, the scene's default camera
(:func:`tessera.geometry.default_camera`), the whole frame drawn and read back ``--frames`` times
after one warm-up frame, at ``--msaa`` where the tree has it (default 1: one sample and no
anti-aliasing filter, the shading alone; 0 is auto). The trees take turns ``--rounds`` times (so a
change in the machine's load falls on both). Per scene and tree: ``wall_ms`` and ``cpu_ms`` (the
process's CPU time, llvmpipe's threads included: it spreads a frame over the cores, so CPU exceeds
wall), the medians over all rounds' frames; ``ratio_wall``/``ratio_cpu`` this tree's over the first
baseline's; ``psnr_db`` this tree's last frame against the baseline's (how much the picture
differs).
"""

from __future__ import annotations

import argparse
import io
import json
import os
import subprocess
import sys
import tarfile
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SHARED_SCENES = REPO.parent / "shared" / "scenes"
DEFAULT_SCENES = tuple(str(SHARED_SCENES / name) for name in (
    "bunny/bun_zipper.ply", "large_scan/stanford_dragon_vrip_res2_202k.ply", "large_scan/stanford_lucy_240k.ply",
    "large_scan/threedscans_pan_990k.ply"))
#: The tree before the glTF metallic-roughness shader (aa1b996's parent): the headlight Lambert shader.
LAMBERT_REVISION = "231a2465d7a63534554e6071640075baa512fedf"
THIS_TREE = "working tree"


def worker(out: Path) -> None:
    """Run in the tree being measured (``node``/``tessera`` first on the path): the scenes, size and
    frames of ``out``/request.json measured, each scene's frame times written to ``out``/times.json and
    its last frame to ``out``/<index>.npy."""
    from node.gl.context import create_gl_context
    from node.gl.renderer import TileRenderer
    from node.scene.loading import load_scene
    from tessera.geometry import default_camera

    request = json.loads((out / "request.json").read_text())
    scenes, size, frames = request["scenes"], tuple(request["size"]), request["frames"]
    try:
        from node.gl.shading import ShadingOptions
        options: dict[str, Any] = {"shading": ShadingOptions(msaa=request["msaa"])}
    except ImportError:   # a tree before anti-aliasing: one sample, no filter
        options = {}
    ctx = create_gl_context()
    found: dict[str, Any] = {}
    for index, spec in enumerate(scenes):
        scene = load_scene(spec)
        camera = default_camera(scene.bounds, aspect=size[0] / size[1])
        renderer = TileRenderer(ctx, scene, **options)
        pixels = renderer.render_frame(camera, size).pixels
        wall, cpu = [], []
        for _ in range(frames):
            started, started_cpu = time.perf_counter(), time.process_time()
            pixels = renderer.render_frame(camera, size).pixels
            wall.append((time.perf_counter() - started) * 1e3)
            cpu.append((time.process_time() - started_cpu) * 1e3)
        np.save(out / f"{index}.npy", pixels)
        renderer.release()
        found[spec] = {"wall_ms": wall, "cpu_ms": cpu}
    ctx.release()
    (out / "times.json").write_text(json.dumps(found))


def extract_tree(revision: str, target: Path) -> Path:
    """``node`` and ``tessera`` of ``revision`` written under ``target``; returns ``target``."""
    archive = subprocess.run(["git", "archive", "--format=tar", revision, "node", "tessera"], cwd=REPO,
                             capture_output=True, check=True).stdout
    target.mkdir(parents=True)
    with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
        tar.extractall(target, filter="data")
    return target


def run_tree(root: Path, scenes: Sequence[str], size: tuple[int, int], frames: int, msaa: int,
             out: Path) -> dict[str, Any]:
    """:func:`worker` in a process of its own with the tree at ``root`` first on the path."""
    out.mkdir(parents=True, exist_ok=True)
    request = {"scenes": list(scenes), "size": list(size), "frames": frames, "msaa": msaa}
    (out / "request.json").write_text(json.dumps(request))
    environment = {**os.environ, "PYTHONPATH": os.pathsep.join([str(root), str(REPO)])}  # bench/ from this checkout
    subprocess.run([sys.executable, "-m", "bench.shading", "--worker", str(out)], cwd=root, env=environment,
                   check=True)
    return json.loads((out / "times.json").read_text())


def measure(trees: dict[str, Path], scenes: Sequence[str], size: tuple[int, int], frames: int,
            rounds: int, scratch: Path, msaa: int = 1) -> dict[str, Any]:
    """The figures of the module docstring; ``trees`` by name, :data:`THIS_TREE` and the baselines."""
    from bench.images import psnr, reported_psnr

    times: dict[str, dict[str, dict[str, list[float]]]] = {
        name: {spec: {"wall_ms": [], "cpu_ms": []} for spec in scenes} for name in trees}
    for round_number in range(rounds):
        for tree_number, (name, root) in enumerate(trees.items()):
            found = run_tree(root, scenes, size, frames, msaa, scratch / f"{tree_number}-{round_number}")
            for spec in scenes:
                for key in ("wall_ms", "cpu_ms"):
                    times[name][spec][key].extend(found[spec][key])
    baselines = [name for name in trees if name != THIS_TREE]
    rows = []
    for index, spec in enumerate(scenes):
        mine = np.load(scratch / f"0-{rounds - 1}" / f"{index}.npy")
        row: dict[str, Any] = {"scene": spec}
        for tree_number, name in enumerate(trees):
            row[name] = {key: float(np.median(times[name][spec][key])) for key in ("wall_ms", "cpu_ms")}
            if name != THIS_TREE:
                theirs = np.load(scratch / f"{tree_number}-{rounds - 1}" / f"{index}.npy")
                row[name]["psnr_db"] = reported_psnr(psnr(mine, theirs))
        first = row[baselines[0]]
        row["ratio_wall"] = row[THIS_TREE]["wall_ms"] / first["wall_ms"]
        row["ratio_cpu"] = row[THIS_TREE]["cpu_ms"] / first["cpu_ms"]
        rows.append(row)
    return {"baselines": baselines, "rows": rows}


def table(result: dict[str, Any]) -> str:
    lines = [f"{'scene':<40} {'tree':<42} {'wall ms':>8} {'CPU ms':>8} {'PSNR dB':>8}"]
    for row in result["rows"]:
        for name in (THIS_TREE, *result["baselines"]):
            figures = row[name]
            psnr_text = f"{figures['psnr_db']:>8.2f}" if "psnr_db" in figures else f"{'':>8}"
            lines.append(f"{Path(row['scene']).name:<40} {name:<42} {figures['wall_ms']:>8.1f} "
                         f"{figures['cpu_ms']:>8.1f} {psnr_text}")
        lines.append(f"{'':<40} {'ratio to ' + result['baselines'][0][:12]:<42} {row['ratio_wall']:>8.2f} "
                     f"{row['ratio_cpu']:>8.2f}")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    if argv is None and sys.argv[1:2] == ["--worker"]:
        worker(Path(sys.argv[2]))
        return 0
    from bench.processes import show_result
    from node.settings import parse_size

    parser = argparse.ArgumentParser(prog="python -m bench.shading", description=__doc__.split("\n\n")[0])
    parser.add_argument("--tree", help="a git revision measured instead of the working tree")
    parser.add_argument("--baseline", action="append",
                        help=f"a git revision to compare with (repeatable; default {LAMBERT_REVISION[:12]}, Lambert)")
    parser.add_argument("--scene", action="append", help="scene (repeatable; default the four scans)")
    parser.add_argument("--size", type=parse_size, default=(1280, 720))
    parser.add_argument("--frames", type=int, default=7)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--msaa", type=int, default=1,
                        help="--msaa of trees that have it (default 1: one sample and no anti-aliasing filter)")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    # Workers run in the trees' directories: file paths made absolute.
    scenes = [str(Path(spec).resolve()) if Path(spec).exists() else spec for spec in args.scene or DEFAULT_SCENES]
    with tempfile.TemporaryDirectory(prefix="tessera-shading-") as scratch:
        trees = {THIS_TREE: REPO if args.tree is None else extract_tree(args.tree, Path(scratch) / "tree")}
        for number, revision in enumerate(args.baseline or [LAMBERT_REVISION]):
            trees[revision] = extract_tree(revision, Path(scratch) / f"tree-{number}")
        result = measure(trees, scenes, args.size, args.frames, args.rounds, Path(scratch), args.msaa)
    show_result(table(result), result, args.json, argv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
