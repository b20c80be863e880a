"""Scaling beyond this machine: the coordinator's own scheduler with 16…256 simulated nodes on a
virtual clock, and a real coordinator over loopback with many synthetic nodes.

``python -m bench.scale [--virtual-nodes 16,64,256] [--loopback-nodes 16,64] [--size 1920x1080]
[--seconds 10] [--json OUT]`` (more: ``--cost-model measured|synthetic``, ``--scene``, ``--grid
16x9``, ``--frames 120``, ``--shift-px 8``, ``--warmup-s 2``, ``--timeout-s``; an empty list, e.g.
``--loopback-nodes ""``, skips that part).

**Virtual part.** The cost model (``--cost-model measured``, the default) renders ``--scene`` with
the real renderer (one GL context, LP_NUM_THREADS=0 set before it so that llvmpipe rasterizes on
the calling thread, CPU culling), camera :func:`tessera.geometry.default_camera`. A phase's time
is the rendering thread's CPU time (the renderer's wall-clock split between render and read-back
scaled to it), the minimum over 3 interleaved rounds; a speed-1 node is thus one llvmpipe thread.

- cells: the frame cut into ``--grid`` cells, each rendered as a tile, read back and JPEG-encoded
  at the coordinator's interactive quality: render, read-back and encode ms per cell;
- per-tile overhead: an 8×8 tile at every cell's centre, timed the same way; the overhead is the
  cheapest one's phases (a tile that draws (almost) nothing: clear, cull, draw setup, finish, read
  back, encode);
- a cell's area cost = its phases − the overhead (at least 0), spread evenly over the cell; a
  tile's cost = the overhead + the area cost of the parts of cells it covers;
- check: the whole frame and its four quadrants rendered for real against the model (busy ms). The
  model counts the geometry work of a chunk that spans several cells once per cell, a tile larger
  than a cell does it once: the check shows how much the model overstates large tiles.

Frame i's map is the measured one rolled cyclically i × ``--shift-px`` pixels to the right (a pan:
the load moves, the total work stays). ``--cost-model synthetic`` (no GL, for tests): a column of
load, 100 ms per frame, across the middle of the screen, 0.45 ms overhead per tile.

For each N and balancer (``static``, ``adaptive``, ``rotate`` and the coordinator's default),
:class:`bench.virtual_cluster.VirtualCluster` runs N speed-1 nodes with ``run_path``'s scheduler
configuration (2 frames in flight, no frame-rate cap, no still frame, no settle frames) over
``--frames`` frames, each camera set the moment the newest one's frame starts (one fixed camera:
the motion is the map's roll). Figures over the frames after the first 10
(:func:`bench.virtual_cluster.summarize`): virtual frames/s = 1000 / ``frame_ms_pipelined``,
``imbalance_mean``, ``efficiency_pipelined``, tiles per frame. Scheduler CPU: the thread CPU time
spent inside the :class:`tessera.scheduling.scheduler.FrameScheduler`'s entry points (:data:`ENTRY_POINTS`;
nested calls counted once; balancer and frame bookkeeping included, the simulation's event heap,
cost model and records not), minus the same wrapper's counted time around a no-op × calls, per
published frame over the whole run; its ceiling = 1000 / that frames/s.

**Loopback part.** For each K of ``--loopback-nodes``, :func:`bench.loopback.run_loopback`: a real
coordinator (every default, no local nodes) over loopback with K synthetic nodes and a closed-loop
viewer, its published frames/s, tiles/s, CPU per frame and the ceiling that gives (see
:mod:`bench.loopback`). ``--timeout-s`` bounds the whole loopback part; every process is stopped
(SIGINT, then SIGKILL) on the way out, errors included.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import platform
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from bench.loopback import run_loopback
from bench.virtual_cluster import Phases, VirtualCluster, summarize
from server.settings import Settings
from tessera.balancers import create_balancer
from tessera.cli_values import size_parser
from tessera.geometry import Camera, Rect, default_camera
from tessera.scheduling.scheduler import SchedulerConfig
from tessera.wire.codec import Codec, encode

REPO = Path(__file__).resolve().parents[1]
DEFAULT_SCENE = str(REPO.parent / "shared" / "scenes" / "large_scan" / "stanford_lucy_240k.ply")
SKIP = 10
REPEATS = 3
TINY_PX = 8
#: FrameScheduler methods the simulation (and the live service) calls
ENTRY_POINTS = ("set_camera", "invalidate", "set_balancer", "add_node", "node_ready", "set_speed", "remove_node",
                "tile_arrived", "tile_sent", "tick", "next_deadline", "drain")


# --------------------------------------------------------------------------------- cost model


@dataclass(frozen=True)
class CostModel:
    """Tile costs on a speed-1 node for frames of ``size`` = (w, h): ``overhead`` (3,) render,
    read-back and encode ms of every tile, ``cells`` (3, rows, cols) those phases' ms beyond the
    overhead per grid cell, spread evenly over the cell."""

    size: tuple[int, int]
    overhead: np.ndarray
    cells: np.ndarray

    def phases(self, rects: Sequence[Rect], shift_px: int = 0) -> list[Phases]:
        """Each rect's phases, the cell map rolled cyclically ``shift_px`` to the right."""
        width, height = self.size
        rows, cols = self.cells.shape[1:]
        r = np.array([[t.x, t.y, t.w, t.h] for t in rects], dtype=np.int64).reshape(-1, 4)
        x0 = (r[:, 0] - shift_px) % width   # where the rect's columns were before the roll
        col_edges = np.concatenate([grid_edges(width, cols), grid_edges(width, cols)[1:] + width])
        across = coverage(x0, x0 + r[:, 2], col_edges)                                     # (R, 2 cols)
        down = coverage(r[:, 1], r[:, 1] + r[:, 3], grid_edges(height, rows))               # (R, rows)
        costs = np.einsum("ri,pij,rj->rp", down, np.concatenate([self.cells, self.cells], axis=2), across)
        return [Phases(*(self.overhead + c)) for c in costs]

    def to_json(self) -> dict[str, Any]:
        return {"size": list(self.size), "overhead_ms": self.overhead.tolist(),
                "cell_busy_ms": self.cells.sum(axis=0).round(4).tolist(),
                "frame_busy_ms": float(self.phases([Rect(0, 0, *self.size)])[0].busy_ms)}


def grid_edges(length: int, count: int) -> np.ndarray:
    """``count`` + 1 integer cell edges over 0…``length`` pixels."""
    return np.arange(count + 1) * length // count


def coverage(lo: np.ndarray, hi: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """(R, K) fraction of each of the K cells between ``edges`` that the spans [lo, hi) cover."""
    overlap = np.minimum(hi[:, None], edges[None, 1:]) - np.maximum(lo[:, None], edges[None, :-1])
    return np.clip(overlap, 0, None) / np.diff(edges)[None, :]


def grid_rects(size: tuple[int, int], grid: tuple[int, int]) -> list[Rect]:
    """The ``grid`` = (cols, rows) cells of a ``size`` frame, row by row."""
    xs, ys = grid_edges(size[0], grid[0]), grid_edges(size[1], grid[1])
    return [Rect(int(xs[i]), int(ys[j]), int(xs[i + 1] - xs[i]), int(ys[j + 1] - ys[j]))
            for j in range(grid[1]) for i in range(grid[0])]


def synthetic_cost_model(size: tuple[int, int], grid: tuple[int, int]) -> CostModel:
    """No GL: 100 ms of work per frame in a column across the middle (a Gaussian of σ = 8 % of the
    width over the rows between 10 % and 90 % of the height), split 80/10/10 % into render, read-back
    and encode; overhead 0.3 + 0.05 + 0.1 ms per tile."""
    cols, rows = grid
    across = np.exp(-0.5 * (((np.arange(cols) + 0.5) / cols - 0.5) / 0.08) ** 2)
    centres = (np.arange(rows) + 0.5) / rows
    busy = np.outer((centres > 0.1) & (centres < 0.9), across)
    busy *= 100.0 / busy.sum()
    return CostModel(size, np.array([0.3, 0.05, 0.1]), np.stack([0.8 * busy, 0.1 * busy, 0.1 * busy]))


def time_tiles(renderer: Any, camera: Camera, size: tuple[int, int], rects: Sequence[Rect],
               quality: int) -> np.ndarray:
    """(R, 3) render, read-back and JPEG-encode ms of each rect: the calling thread's CPU time (the
    renderer's wall-clock split between render and read-back scaled to it), each phase's minimum
    over :data:`REPEATS` rounds of every rect once."""
    samples = np.empty((REPEATS, len(rects), 3))
    for round_samples in samples:
        for i, rect in enumerate(rects):
            started = time.thread_time()
            tile = renderer.render_tile(camera, size, rect)
            drawn = time.thread_time()
            encode(tile.pixels, Codec.JPEG, quality)
            cpu_ms, wall_ms = (drawn - started) * 1e3, tile.render_ms + tile.readback_ms
            render_share = tile.render_ms / wall_ms if wall_ms > 0.0 else 1.0
            round_samples[i] = (cpu_ms * render_share, cpu_ms * (1.0 - render_share),
                                (time.thread_time() - drawn) * 1e3)
    return samples.min(axis=0)


def measure_cost_model(scene_spec: str, size: tuple[int, int], grid: tuple[int, int],
                       quality: int) -> tuple[CostModel, dict[str, Any]]:
    """The measured model (see the module docstring) and what was measured: renderer, scene, camera,
    seconds, and the model check (rect, measured and model busy ms). The CPU clock needs llvmpipe on
    the calling thread: LP_NUM_THREADS=0 set before this process's first GL context."""
    from node.culling.switch import CullMode
    from node.gl.context import create_gl_context, renderer_string
    from node.gl.renderer import TileRenderer
    from node.scene.loading import load_scene

    started = time.perf_counter()
    scene = load_scene(scene_spec)
    camera = default_camera(scene.bounds, aspect=size[0] / size[1])
    ctx = create_gl_context()
    renderer = TileRenderer(ctx, scene, culling=CullMode.CPU)
    try:
        full = Rect(0, 0, *size)
        time_tiles(renderer, camera, size, [full], quality)   # warm-up: shaders, first touch
        cells = grid_rects(size, grid)
        cell_ms = time_tiles(renderer, camera, size, cells, quality)
        tiny = [Rect(min(c.x + c.w // 2, size[0] - TINY_PX), min(c.y + c.h // 2, size[1] - TINY_PX), TINY_PX, TINY_PX)
                for c in cells]
        tiny_ms = time_tiles(renderer, camera, size, tiny, quality)
        overhead = tiny_ms[np.argmin(tiny_ms.sum(axis=1))]
        area = np.clip(cell_ms - overhead, 0.0, None).reshape(grid[1], grid[0], 3).transpose(2, 0, 1)
        model = CostModel(size, overhead, area)
        half_w, half_h = size[0] // 2, size[1] // 2
        checks = [full, Rect(0, 0, half_w, half_h), Rect(half_w, 0, size[0] - half_w, half_h),
                  Rect(0, half_h, half_w, size[1] - half_h), Rect(half_w, half_h, size[0] - half_w, size[1] - half_h)]
        measured = time_tiles(renderer, camera, size, checks, quality).sum(axis=1)
        info = {"kind": "measured", "scene": scene_spec, "triangles": scene.triangle_count,
                "camera": camera.to_json(), "grid": list(grid), "jpeg_quality": quality,
                "renderer": renderer_string(ctx), "lp_num_threads": os.environ.get("LP_NUM_THREADS"),
                "tiny_px": TINY_PX, "repeats": REPEATS,
                "check": [{"rect": rect.as_list(), "measured_ms": float(ms), "model_ms": p.busy_ms}
                          for rect, ms, p in zip(checks, measured, model.phases(checks), strict=True)]}
    finally:
        renderer.release()
        ctx.release()
    info["seconds"] = time.perf_counter() - started
    return model, info


# --------------------------------------------------------------------------------- virtual part


class EntryPointCpu:
    """Thread CPU seconds spent inside ``target``'s methods ``names`` (wrapped on the instance; a
    call made from inside another counts once, with the outer one) and how many calls."""

    def __init__(self, target: Any, names: Sequence[str]) -> None:
        self.seconds = 0.0
        self.calls = 0
        self._depth = 0
        for name in names:
            setattr(target, name, self._timed(getattr(target, name)))

    def _timed(self, method: Callable[..., Any]) -> Callable[..., Any]:
        @functools.wraps(method)
        def timed(*args: Any, **kwargs: Any) -> Any:
            if self._depth:
                return method(*args, **kwargs)
            self._depth += 1
            started = time.thread_time()
            try:
                return method(*args, **kwargs)
            finally:
                self.seconds += time.thread_time() - started
                self.calls += 1
                self._depth -= 1
        return timed


def wrapper_seconds_per_call(calls: int = 50_000) -> float:
    """Thread CPU seconds :class:`EntryPointCpu` counts per call of a no-op: its own share."""
    target = SimpleNamespace(noop=lambda: None)
    cpu = EntryPointCpu(target, ["noop"])
    for _ in range(calls):
        target.noop()
    return cpu.seconds / cpu.calls


def run_virtual(model: CostModel, nodes: int, balancer: str, frames: int, shift_px: int,
                wrapper_s: float) -> dict[str, Any]:
    """One virtual run (see the module docstring); its figures."""
    config = SchedulerConfig(size=model.size, max_in_flight=2, max_fps=1e9, still_codec=None, settle_frames=0,
                             tile_timeout_s=1e9)

    def measure(camera: int, rects: Sequence[Rect]) -> list[Phases]:
        return model.phases(rects, camera * shift_px)

    started = time.perf_counter()
    cluster = VirtualCluster(config, create_balancer(balancer), measure, dict.fromkeys(range(1, nodes + 1), 1.0))
    cpu = EntryPointCpu(cluster.scheduler, ENTRY_POINTS)
    camera = default_camera(np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]), aspect=model.size[0] / model.size[1])
    records = cluster.run([camera] * frames)
    summary = summarize(records, SKIP)
    cpu_ms = (cpu.seconds - cpu.calls * wrapper_s) * 1e3 / len(records)
    tiles = float(np.mean([len(r.partition.tiles) for r in records[SKIP:]]))
    return {"nodes": nodes, "balancer": balancer, "fps_virtual": 1000.0 / summary["frame_ms_pipelined"],
            "frame_ms_pipelined": summary["frame_ms_pipelined"], "imbalance_mean": summary["imbalance_mean"],
            "efficiency_pipelined": summary["efficiency_pipelined"], "tiles_per_frame": tiles,
            "work_ms": summary["work_ms"], "frames": len(records),
            "frames_cancelled": cluster.scheduler.frames_cancelled,
            "scheduler_cpu_ms_per_frame": cpu_ms, "scheduler_calls_per_frame": cpu.calls / len(records),
            "scheduler_ceiling_fps": 1000.0 / cpu_ms, "scheduler_ceiling_tiles_per_s": 1000.0 / cpu_ms * tiles,
            "wall_s": time.perf_counter() - started}


# --------------------------------------------------------------------------------- command line


def node_counts(text: str) -> list[int]:
    """``16,64`` → [16, 64]; an empty string → [] (the part is skipped)."""
    try:
        counts = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"node counts are whole numbers separated by commas, got {text!r}") from None
    if any(n < 1 for n in counts):
        raise argparse.ArgumentTypeError(f"node counts must be >= 1, got {text!r}")
    return counts


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m bench.scale", description=__doc__.split("\n\n")[0])
    parser.add_argument("--virtual-nodes", type=node_counts, default=[16, 64, 256])
    parser.add_argument("--loopback-nodes", type=node_counts, default=[16, 64])
    parser.add_argument("--size", type=size_parser(16, 8192), default=(1920, 1080))
    parser.add_argument("--seconds", type=float, default=10.0, help="loopback measuring window (default 10)")
    parser.add_argument("--warmup-s", type=float, default=2.0, help="loopback warm-up before the window (default 2)")
    parser.add_argument("--timeout-s", type=float,
                        help="hard limit of the whole loopback part (default 60 + 2 × (seconds + warm-up) per run)")
    parser.add_argument("--cost-model", choices=("measured", "synthetic"), default="measured")
    parser.add_argument("--scene", default=DEFAULT_SCENE, help="scene of the measured cost model (default Lucy)")
    parser.add_argument("--grid", type=size_parser(1, 512), default=(16, 9), help="cost cells COLSxROWS (16x9)")
    parser.add_argument("--frames", type=int, default=120, help="virtual frames per run (default 120)")
    parser.add_argument("--shift-px", type=int, default=8, help="cost map roll per frame, px (default 8)")
    parser.add_argument("--json", type=Path, help="write every figure here")
    return parser


def virtual_table(runs: list[dict[str, Any]], default: str) -> str:
    lines = [f"{'nodes':>5}  {'balancer':<18} {'fps':>8} {'frame ms':>8} {'imbal':>6} {'eff':>6} {'tiles/f':>7} "
             f"{'sched ms/f':>10} {'ceil fps':>9} {'ceil tiles/s':>12} {'wall s':>6}"]
    for r in runs:
        name = r["balancer"] + (" (default)" if r["balancer"] == default else "")
        lines.append(f"{r['nodes']:>5}  {name:<18} {r['fps_virtual']:>8.1f} {r['frame_ms_pipelined']:>8.2f} "
                     f"{r['imbalance_mean']:>6.3f} {r['efficiency_pipelined']:>6.3f} {r['tiles_per_frame']:>7.0f} "
                     f"{r['scheduler_cpu_ms_per_frame']:>10.3f} {r['scheduler_ceiling_fps']:>9.0f} "
                     f"{r['scheduler_ceiling_tiles_per_s']:>12.0f} {r['wall_s']:>6.1f}")
    return "\n".join(lines)


def loopback_table(runs: list[dict[str, Any]]) -> str:
    lines = [f"{'nodes':>5} {'fps':>7} {'tiles/s':>8} {'tiles/f':>7} {'coord ms/f':>10} {'recv ms/f':>9} "
             f"{'pub ms/f':>8} {'coord cores':>11} {'nodes ms/f':>10} {'ceil fps':>8} {'ceil tiles/s':>12} "
             f"{'viewer fps':>10} {'KB/f':>6} {'cancelled':>9}"]
    for r in runs:
        lines.append(f"{r['nodes']:>5} {r['fps']:>7.1f} {r['tiles_per_s']:>8.0f} {r['tiles_per_frame']:>7.1f} "
                     f"{r['coordinator_cpu_ms_per_frame']:>10.2f} {r['receive_cpu_ms_per_frame']:>9.2f} "
                     f"{r['publish_cpu_ms_per_frame']:>8.2f} {r['coordinator_cores']:>11.2f} "
                     f"{r['nodes_cpu_ms_per_frame']:>10.2f} {r['ceiling_fps']:>8.0f} {r['ceiling_tiles_per_s']:>12.0f} "
                     f"{r['viewer_fps']:>10.1f} {r['viewer_kb_per_frame']:>6.1f} {r['frames_cancelled']:>9d}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.frames <= SKIP + 2 or args.seconds <= 0.0 or args.warmup_s < 0.0:
        parser.error(f"--frames must be > {SKIP + 2}, --seconds > 0, --warmup-s >= 0")
    settings = Settings()
    size = args.size
    result: dict[str, Any] = {}
    print(f"Tessera scale benchmark at {size[0]}x{size[1]}; this machine: {os.cpu_count()} CPUs", flush=True)

    if args.virtual_nodes:
        if args.cost_model == "measured":
            os.environ["LP_NUM_THREADS"] = "0"
            model, model_info = measure_cost_model(args.scene, size, args.grid, settings.interactive_quality)
        else:
            model, model_info = synthetic_cost_model(size, args.grid), {"kind": "synthetic", "grid": list(args.grid)}
        model_info.update(model.to_json())
        overhead = model.overhead
        print(f"\nVirtual cluster: cost model {model_info['kind']}"
              + (f" ({Path(args.scene).name}, {model_info['renderer']}, {model_info['seconds']:.1f} s)"
                 if args.cost_model == "measured" else "")
              + f"; whole frame {model_info['frame_busy_ms']:.1f} ms at speed 1; per-tile overhead "
              f"{overhead.sum():.3f} ms (render {overhead[0]:.3f}, read-back {overhead[1]:.3f}, encode "
              f"{overhead[2]:.3f}); map rolled {args.shift_px} px per frame; {args.frames} frames, figures after "
              f"{SKIP}", flush=True)
        for check in model_info.get("check", []):
            print(f"  model check {check['rect']}: measured {check['measured_ms']:.2f} ms, model "
                  f"{check['model_ms']:.2f} ms", flush=True)
        wrapper_s = wrapper_seconds_per_call()
        balancers = list(dict.fromkeys(["static", "adaptive", "rotate", settings.balancer]))
        runs = []
        for nodes in args.virtual_nodes:
            for name in balancers:
                runs.append(run_virtual(model, nodes, name, args.frames, args.shift_px, wrapper_s))
                print(f"  [{nodes} nodes, {name}] {runs[-1]['wall_s']:.1f} s", flush=True)
        print(virtual_table(runs, settings.balancer))
        print(f"sched ms/f: thread CPU inside the FrameScheduler's entry points per published frame (wrapper's "
              f"own {wrapper_s * 1e6:.2f} µs per call taken off); ceil: 1000 / that")
        result["virtual"] = {"cost_model": model_info, "wrapper_us_per_call": wrapper_s * 1e6,
                             "balancers": balancers, "default_balancer": settings.balancer, "skip": SKIP,
                             "frames": args.frames, "shift_px": args.shift_px, "runs": runs}

    if args.loopback_nodes:
        timeout_s = args.timeout_s or len(args.loopback_nodes) * (60.0 + 2.0 * (args.seconds + args.warmup_s))
        deadline = time.monotonic() + timeout_s
        print(f"\nLoopback: a real coordinator (every default: balancer {settings.balancer}, frame-rate cap "
              f"{settings.max_fps:g}/s), synthetic nodes "
              f"answering at once with pre-encoded tiles, a closed-loop viewer; {args.warmup_s:g} s warm-up, "
              f"{args.seconds:g} s window", flush=True)
        runs = []
        for nodes in args.loopback_nodes:
            remaining = deadline - time.monotonic()
            if remaining <= 0.0:
                raise TimeoutError(f"the loopback part ran over --timeout-s {timeout_s:g}")
            runs.append(run_loopback(nodes, size, args.seconds, args.warmup_s, remaining))
            for line in runs[-1]["coordinator_log"][1:]:   # after "Tessera serving on …"
                print(f"  coordinator: {line}")
        print(loopback_table(runs))
        print("coord ms/f: coordinator process CPU (/proc utime + stime) per published frame; recv/pub: its tile "
              "receive and publish handlers' thread CPU; ceil: 1000 / coord ms/f, × tiles per frame")
        result["loopback"] = {"timeout_s": timeout_s, "warmup_s": args.warmup_s, "max_fps": settings.max_fps,
                              "runs": runs}

    if args.json:
        result["meta"] = {"argv": sys.argv[1:] if argv is None else list(argv), "python": platform.python_version(),
                          "cpus": os.cpu_count(), "platform": platform.platform(), "size": list(size),
                          "seconds": args.seconds}
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=2) + "\n")
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
