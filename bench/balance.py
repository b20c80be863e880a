"""Serial-replay balancing benchmark: every balancer on the same camera path, every tile rendered.

``python -m bench.balance --scene PATH --path PATH.json --nodes N --size WxH --balancers a,b,…
[--speeds s1,s2,…] [--lag 1] [--repeats 3] [--frames F] [--json OUT]``

For every frame and balancer the balancer's tiles are rendered for real, one at a time, in one GL
context (so the machine's shared cores do not blur node times), and the measured phases are fed
back as the live coordinator feeds them (:mod:`bench.replay`). Node i's times are multiplied by
sᵢ from ``--speeds`` — sᵢ is a *slowdown*: sᵢ = 2 makes node i twice as slow, like ``python -m
node --slowdown 2``. Node weights are the coordinator's calibration (seed 003 §1): each node's time
on :func:`tessera.balancers.hetero.calibration_region` of the first camera × sᵢ →
:func:`tessera.balancers.hetero.calibration_weights`, the same weights for every balancer.

Noise control (the machine's two cores are shared with other work): llvmpipe runs on the calling
thread (``LP_NUM_THREADS`` = 0, set before the GL context is created) and a phase's time is that
thread's CPU time (``--clock cpu``; the renderer's wall-clock split between render and read-back
scaled to it), so time the thread was preempted does not count; a frame's tiles are timed in
interleaved rounds (every tile once, then again) so they see the same machine conditions; each
phase is the minimum over ``--repeats`` renders, with further rounds for tiles whose two fastest
busy times differ by more than 3 % (at most 3 × ``--repeats``); a tile's times are memoized per
(frame, rect), so balancers that choose the same tile see the same cost. ``--noise-check`` (on by
default) re-times the equal split's tiles at the end and reports how much a frame's max/mean moved.
Busy time = render + read-back + encode (``tessera.codec.encode``, JPEG q85 by default, as the
nodes do); send time is not modelled (no network). Culling is per tile on the CPU by default
(the hybrid CPU/GPU switch keeps per-slot history, which a memoized replay cannot honour). For
figures, run it as its own process: in a process that already made a GL context the
``LP_NUM_THREADS`` it sets may not take effect.

Prints a header, a progress line per balancer and a table; ``--json OUT`` writes
``{balancer: {imbalance_mean, imbalance_p95, efficiency, repartitions, frames, frame_ms, work_ms,
efficiency_pipelined, frame_ms_pipelined}, "meta": {...}}`` over the frames after the first
``--skip`` (10). ``efficiency`` scores each frame alone (a pull list by its one-frame makespan);
``efficiency_pipelined`` runs the same tiles through the live coordinator's timeline with
``--lag`` + 1 frames in flight, where a node done with its part of a frame starts on the next
(:class:`bench.replay.Pipeline`), counting the work done between the last left-out frame's
completion and the last frame's.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bench.replay import Phases, replay, summarize
from node.culling_state import CullMode
from tessera.balancers import BALANCERS, create_balancer
from tessera.balancers.base import BalanceInput
from tessera.balancers.hetero import calibration_region, calibration_weights
from tessera.balancers.static import StaticBalancer
from tessera.codec import Codec, encode
from tessera.geometry import Camera, Rect
from tessera.projection import project_groups

DEFAULT_SKIP = 10
DEFAULT_LP_THREADS = 0
#: a tile is re-rendered until its two fastest busy times agree within this fraction
TOLERANCE = 0.03


def parse_size(text: str) -> tuple[int, int]:
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"size must be WxH, got {text!r}") from None
    if width < 1 or height < 1:
        raise argparse.ArgumentTypeError(f"size must be positive, got {text!r}")
    return width, height


def parse_speeds(text: str) -> list[float]:
    try:
        speeds = [float(v) for v in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"speeds must be numbers separated by commas, got {text!r}") from None
    if any(not s > 0.0 for s in speeds):
        raise argparse.ArgumentTypeError("speeds (slowdown factors) must be > 0")
    return speeds


def load_path(path: Path, frames: int | None) -> tuple[float, list[Camera]]:
    """The path's ``dt_ms`` and cameras (the first ``frames`` of them when given)."""
    data = json.loads(path.read_text())
    cameras = [Camera.from_json(c) for c in data["frames"]]
    dt_ms = float(data["dt_ms"])
    if not dt_ms > 0.0 or not cameras:
        raise ValueError(f"{path}: needs dt_ms > 0 and at least one camera")
    return dt_ms, cameras[:frames] if frames else cameras


class TileTimer:
    """``measure(frame, rects)`` for :func:`bench.replay.replay`: renders a frame's tiles
    ``repeats`` times, interleaved (every tile once, then again), so that all of a frame's tiles
    are timed under the same machine conditions; keeps each phase's minimum; memoized per
    (frame, rect). ``cpu_clock``: a phase's time is the calling thread's CPU time (the renderer's
    wall-clock split between render and read-back scaled to it) — immune to preemption by other
    processes, exact when llvmpipe runs on the calling thread (LP_NUM_THREADS=0)."""

    def __init__(self, renderer: Any, cameras: Sequence[Camera], size: tuple[int, int], codec: Codec,
                 jpeg_quality: int, repeats: int, cpu_clock: bool = True, tolerance: float = 0.03,
                 max_repeats: int | None = None) -> None:
        self.renderer, self.cameras, self.size = renderer, cameras, size
        self.codec, self.jpeg_quality, self.repeats, self.cpu_clock = codec, jpeg_quality, repeats, cpu_clock
        self.tolerance, self.max_repeats = tolerance, max(repeats, max_repeats or 3 * repeats)
        self.cache: dict[tuple[int, int, int, int, int], Phases] = {}
        self.renders = 0
        self.hits = 0

    def _once(self, camera: Camera, rect: Rect, encode_pixels: bool) -> tuple[float, float, float]:
        """One render (+ encode) of ``rect``: render, read-back and encode ms."""
        cpu_started = time.thread_time()
        tile = self.renderer.render_tile(camera, self.size, rect, slot="bench")
        cpu_ms = (time.thread_time() - cpu_started) * 1e3
        wall_ms = tile.render_ms + tile.readback_ms
        scale = cpu_ms / wall_ms if self.cpu_clock and wall_ms > 0.0 else 1.0
        encode_ms = 0.0
        if encode_pixels:
            clock = time.thread_time if self.cpu_clock else time.perf_counter
            started = clock()
            encode(tile.pixels, self.codec, self.jpeg_quality)
            encode_ms = (clock() - started) * 1e3
        self.renders += 1
        return tile.render_ms * scale, tile.readback_ms * scale, encode_ms

    def time_rects(self, camera: Camera, rects: Sequence[Rect], encode_pixels: bool = True) -> list[Phases]:
        """Each rect's minimum render, read-back and encode ms over ``repeats`` interleaved rounds,
        then further rounds of the tiles whose two fastest busy times still differ by more than
        ``tolerance`` (at most ``max_repeats`` renders of a tile)."""
        samples: list[list[tuple[float, float, float]]] = [[] for _ in rects]
        pending = list(range(len(rects)))
        while pending:
            for i in pending:
                samples[i].append(self._once(camera, rects[i], encode_pixels))
            pending = [i for i in range(len(rects)) if len(samples[i]) < self.repeats
                       or (len(samples[i]) < self.max_repeats and not self._settled(samples[i]))]
        return [Phases(*(min(s[k] for s in tile) for k in range(3))) for tile in samples]

    def _settled(self, samples: list[tuple[float, float, float]]) -> bool:
        """True with a single repeat asked for, or when the two fastest busy times agree."""
        if self.repeats < 2:
            return True
        first, second = sorted(sum(s) for s in samples)[:2]
        return second <= first * (1.0 + self.tolerance)

    def __call__(self, frame: int, rects: Sequence[Rect]) -> list[Phases]:
        keys = [(frame, r.x, r.y, r.w, r.h) for r in rects]
        missing = {key: rect for key, rect in zip(keys, rects, strict=True) if key not in self.cache}
        self.hits += len(keys) - len(missing)
        self.cache.update(zip(missing, self.time_rects(self.cameras[frame], list(missing.values())), strict=True))
        return [self.cache[key] for key in keys]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m bench.balance", description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", required=True, help="scene file or builtin:NAME")
    parser.add_argument("--path", required=True, type=Path, help="camera path JSON (bench/paths/*.json)")
    parser.add_argument("--nodes", type=int, default=4)
    parser.add_argument("--size", type=parse_size, default=(640, 480), help="WxH (default 640x480)")
    parser.add_argument("--balancers", default=",".join(BALANCERS),
                        help=f"comma-separated names (default all: {','.join(BALANCERS)})")
    parser.add_argument("--speeds", type=parse_speeds,
                        help="slowdown factor per node: node i's times × sᵢ (2 = twice as slow); default all 1")
    parser.add_argument("--lag", type=int, default=1, choices=(0, 1),
                        help="frame f gets frame f-1-lag's timings (1 = 2 frames in flight, as live)")
    parser.add_argument("--repeats", type=int, default=3, help="renders per tile; each phase's minimum is kept")
    parser.add_argument("--frames", type=int, help="replay only the path's first FRAMES cameras")
    parser.add_argument("--skip", type=int, default=DEFAULT_SKIP, help="frames left out of the figures")
    parser.add_argument("--lp-threads", type=int,
                        default=int(os.environ.get("LP_NUM_THREADS", DEFAULT_LP_THREADS)),
                        help="LP_NUM_THREADS for llvmpipe, set before the GL context (default %(default)s; "
                             "0 = rasterize on the calling thread)")
    parser.add_argument("--clock", choices=("cpu", "wall"), default="cpu",
                        help="cpu: the rendering thread's CPU time (needs --lp-threads 0); wall: perf_counter")
    parser.add_argument("--culling", default="cpu", choices=[mode.value for mode in CullMode],
                        help="per-tile culling (default cpu)")
    parser.add_argument("--codec", type=Codec.parse, default=Codec.JPEG, help="tile codec timed (default jpeg)")
    parser.add_argument("--jpeg-quality", type=int, default=85)
    parser.add_argument("--noise-check", action=argparse.BooleanOptionalAction, default=True,
                        help="re-time the equal split's tiles at the end and report how much they moved")
    parser.add_argument("--json", type=Path, help="write the figures here")
    return parser


def check_args(parser: argparse.ArgumentParser, args: argparse.Namespace) -> list[str]:
    """The balancer names; exits through ``parser.error`` on bad arguments."""
    names = [n.strip() for n in args.balancers.split(",") if n.strip()]
    unknown = [n for n in names if n not in BALANCERS]
    if not names or unknown:
        parser.error(f"unknown balancers {unknown}; choose from {', '.join(BALANCERS)}")
    if args.nodes < 1 or args.repeats < 1 or args.skip < 0 or args.lp_threads < 0:
        parser.error("--nodes and --repeats must be >= 1, --skip and --lp-threads >= 0")
    if args.clock == "cpu" and args.lp_threads != 0:
        parser.error("--clock cpu times the calling thread: it needs --lp-threads 0 (or use --clock wall)")
    if args.speeds is not None and len(args.speeds) != args.nodes:
        parser.error(f"--speeds needs {args.nodes} values (one per node), got {len(args.speeds)}")
    return names


def format_table(results: dict[str, dict[str, float | int]]) -> str:
    columns = ("imbalance_mean", "imbalance_p95", "efficiency", "efficiency_pipelined", "repartitions", "frames",
               "frame_ms", "frame_ms_pipelined", "work_ms")
    width = max(len("balancer"), *(len(n) for n in results))
    lines = [f"{'balancer':<{width}}  " + "  ".join(f"{c.replace('_pipelined', '_pipe'):>14}" for c in columns)]
    for name, row in results.items():
        cells = [f"{row[c]:>14d}" if isinstance(row[c], int) else f"{row[c]:>14.3f}" for c in columns]
        lines.append(f"{name:<{width}}  " + "  ".join(cells))
    return "\n".join(lines)


def noise_check(timer: TileTimer, rects: Sequence[Rect], frames: int) -> dict[str, float]:
    """Re-time the tiles ``rects`` of every frame once more (the first timing from the memo, so
    the same as a balancer saw) and compare: mean and max change of a frame's max/mean over the
    tiles, median relative change of a tile's busy time."""
    changes, relative = [], []
    for frame in range(frames):
        first = np.array([p.busy_ms for p in timer(frame, rects)])
        second = np.array([p.busy_ms for p in timer.time_rects(timer.cameras[frame], rects)])
        changes.append(abs(first.max() / first.mean() - second.max() / second.mean()))
        relative.extend(np.abs(second - first) / first)
    return {"imbalance_change_mean": float(np.mean(changes)), "imbalance_change_max": float(np.max(changes)),
            "tile_change_median": float(np.median(relative))}


def header_lines(args: argparse.Namespace, scene: Any, cameras: Sequence[Camera], dt_ms: float,
                 slowdowns: dict[int, float], weights: dict[int, float], calibration_ms: float,
                 renderer_name: str) -> list[str]:
    speeds = ",".join(f"{s:g}" for s in slowdowns.values())
    quality = f" q{args.jpeg_quality}" if args.codec is Codec.JPEG else ""
    return [
        "Tessera serial-replay balancing benchmark",
        f"  scene     {args.scene} ({scene.triangle_count} triangles, {len(scene.groups.counts)} primitive groups)",
        f"  path      {args.path}: {len(cameras)} frames, dt {dt_ms:g} ms; figures over frames "
        f"{args.skip}..{len(cameras) - 1}",
        f"  nodes     {args.nodes} at {args.size[0]}x{args.size[1]}; speeds {speeds} are slowdown factors: node i's "
        "measured times × sᵢ (2 = twice as slow, as node --slowdown)",
        f"  weights   calibration region {calibration_region(args.size).as_list()} {calibration_ms:.2f} ms × sᵢ → "
        + ", ".join(f"{n}: {w:.3f}" for n, w in weights.items()),
        f"  lag       {args.lag}: frame f is partitioned with frame f-{1 + args.lag}'s timings"
        + (" (2 frames in flight, as the live coordinator)" if args.lag == 1 else ""),
        f"  noise     tiles rendered one at a time in one GL context; LP_NUM_THREADS={args.lp_threads} set before "
        f"it; clock: {'rendering thread CPU time' if args.clock == 'cpu' else 'wall'}; a frame's tiles timed in "
        f"interleaved rounds, each phase the minimum of >= {args.repeats} renders (more until the two fastest agree "
        f"within {TOLERANCE:.0%}, at most {3 * args.repeats}); memoized per (frame, rect)",
        f"  busy      render + readback + encode ({args.codec.name.lower()}{quality}); send not modelled; "
        f"culling {args.culling}",
        f"  renderer  {renderer_name}",
    ]


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    names = check_args(parser, args)
    dt_ms, cameras = load_path(args.path, args.frames)
    if len(cameras) <= args.skip:
        parser.error(f"the path has {len(cameras)} frames; the figures need more than --skip {args.skip}")
    os.environ["LP_NUM_THREADS"] = str(args.lp_threads)
    from node.gl_context import create_gl_context, renderer_string
    from node.renderer import TileRenderer
    from node.scene import load_scene

    started = time.perf_counter()
    scene = load_scene(args.scene)
    ctx = create_gl_context()
    renderer = TileRenderer(ctx, scene, culling=CullMode(args.culling))
    size = args.size
    timer = TileTimer(renderer, cameras, size, args.codec, args.jpeg_quality, args.repeats, args.clock == "cpu",
                      TOLERANCE)
    timer.time_rects(cameras[0], [Rect(0, 0, *size)])  # warm-up: shader compilation, first touch
    node_ids = list(range(1, args.nodes + 1))
    slowdowns = dict(zip(node_ids, args.speeds or [1.0] * args.nodes, strict=True))
    calibration_ms = timer.time_rects(cameras[0], [calibration_region(size)], encode_pixels=False)[0].busy_ms
    weights = calibration_weights({n: calibration_ms * s for n, s in slowdowns.items()})
    groups = [project_groups(scene.groups.boxes, scene.groups.counts, c, size, scene.bounds) for c in cameras]
    renderer_name = renderer_string(ctx)
    print("\n".join(header_lines(args, scene, cameras, dt_ms, slowdowns, weights, calibration_ms, renderer_name)),
          flush=True)

    results: dict[str, dict[str, float | int]] = {}
    for name in names:
        balancer_started, renders_before = time.perf_counter(), timer.renders
        records = replay(create_balancer(name), len(cameras), size, node_ids, timer, slowdowns, weights, dt_ms,
                         args.lag, groups.__getitem__)
        results[name] = summarize(records, args.skip)
        print(f"  [{name}] {len(records)} frames in {time.perf_counter() - balancer_started:.1f} s, "
              f"{timer.renders - renders_before} renders (memo {len(timer.cache)} tiles, {timer.hits} hits); "
              f"imbalance_mean {results[name]['imbalance_mean']:.3f}, efficiency {results[name]['efficiency']:.3f}, "
              f"pipelined {results[name]['efficiency_pipelined']:.3f}", flush=True)
    noise = None
    if args.noise_check:
        equal = StaticBalancer().partition(BalanceInput(size=size, node_ids=tuple(node_ids))).rects
        noise = noise_check(timer, equal, len(cameras))
    total_s = time.perf_counter() - started
    renderer.release()
    ctx.release()
    print()
    print(format_table(results))
    if noise is not None:
        print(f"\nnoise: re-timing the equal split's tiles changed a frame's max/mean by "
              f"{noise['imbalance_change_mean']:.3f} on average (max {noise['imbalance_change_max']:.3f}); "
              f"median tile change {noise['tile_change_median']:.1%}")
    print(f"{total_s:.1f} s in all, {timer.renders} tile renders")
    if args.json:
        meta = {"scene": args.scene, "path": str(args.path), "frames": len(cameras), "dt_ms": dt_ms,
                "skip": args.skip, "nodes": args.nodes, "size": list(size), "speeds": list(slowdowns.values()),
                "speeds_meaning": "slowdown factors: node i's measured times are multiplied by s_i",
                "weights": {str(n): w for n, w in weights.items()}, "calibration_ms": calibration_ms,
                "lag": args.lag, "repeats": args.repeats, "tolerance": TOLERANCE, "lp_num_threads": args.lp_threads,
                "clock": args.clock, "culling": args.culling, "codec": args.codec.name.lower(),
                "jpeg_quality": args.jpeg_quality, "renderer": renderer_name, "noise": noise,
                "renders": timer.renders, "seconds": round(total_s, 1), "python": platform.python_version(),
                "argv": sys.argv[1:] if argv is None else list(argv)}
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({**results, "meta": meta}, indent=2) + "\n")
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
