"""Balancing benchmark: every balancer on the same camera path through the coordinator's own
scheduler on a virtual clock, every tile rendered for real.

``python -m bench.balance --scene PATH --path PATH.json --nodes N --size WxH --balancers a,b,…
[--speeds s1,s2,…] [--in-flight 2] [--pace free|path] [--repeats 3] [--frames F]
[--time-per-frame S [--start-time T]] [--json OUT] [--trace OUT]``

Frames are scheduled by the live coordinator's :class:`tessera.scheduling.scheduler.FrameScheduler`, driven on
a virtual clock by :func:`bench.virtual_cluster.run_path`: at most ``--in-flight`` frames in flight
(2, as the live coordinator; ``--lag L`` is the old form of ``--in-flight L+1``); a frame starts
when a node has nothing left to do and takes the newest camera; the balancer gets the timings of
the newest frame complete by then, the previous partition, the node weights, the virtual time
since the last partition and, for techniques that read them, the projected primitive groups.
Each camera of the path is set the moment a frame starts with the one before, so every camera is
rendered once: as fast as the cluster goes (``--pace free``) or with frame starts at most the
path's ``1000 / dt_ms`` per second (``--pace path``). Push tiles queue per node; pull tiles (tile
rotation) go to whichever node is free. A node's tile time is the tile's measured busy time × sᵢ
from ``--speeds`` — sᵢ is a *slowdown*: sᵢ = 2 makes node i twice as slow, like ``python -m node
--slowdown 2``. Node weights are the coordinator's calibration (seed 003 §1): each node's time on
:func:`tessera.balancers.hetero.calibration_region` of the first camera × sᵢ →
:func:`tessera.balancers.hetero.calibration_weights`, the same weights for every balancer.

Tile times (:class:`TileTimer`): every tile is rendered in one GL context, one at a time (so the
machine's shared cores do not blur node times). Noise control (the machine's two cores are shared
with other work): llvmpipe runs on the calling thread (``LP_NUM_THREADS`` = 0, set before the GL
context is created) and a phase's time is that thread's CPU time (``--clock cpu``; the renderer's
wall-clock split between render and read-back scaled to it), so time the thread was preempted
does not count; a frame's tiles are timed in interleaved rounds (every tile once, then again) so
they see the same machine conditions; each phase is the minimum over ``--repeats`` renders, with
further rounds for tiles whose two fastest busy times differ by more than 3 % (at most 3 ×
``--repeats``); a tile's times are memoized per (frame, rect), so balancers that choose the same
tile see the same cost. ``--noise-check`` (on by default) re-times the equal split's tiles at the
end and reports how much a frame's max/mean moved. Busy time = render + read-back + encode
(``tessera.wire.codec.encode``, JPEG q85 by default, as the nodes do); send time is not modelled (no
network). Culling is per tile on the CPU by default (the hybrid CPU/GPU switch keeps per-slot
history, which memoized tile times cannot honour). ``--param NAME=VALUE`` sets a parameter of each
chosen balancer that has it (``--param tiles_per_node=4``: rotate's and rotate-predict's tiles a
node). For figures, run it as its own process: in a process that already made a GL context the
``LP_NUM_THREADS`` it sets may not take effect.

An animated scene (issue 11) plays along the path with ``--time-per-frame S``: camera i is drawn in
the scene's state at ``--start-time`` + i·S seconds (its animations sampled there; memoized with
the tile), and the primitive groups the balancers get are moved with their objects into that
state (:func:`tessera.balancers.projection.posed_groups`), as the live coordinator does; moved objects are
culled where they are (:mod:`node.culling.objects`). Without it every frame shows the base pose.

Prints a header, a progress line per balancer and a table; ``--json OUT`` writes
``{balancer: {imbalance_mean, imbalance_p95, efficiency, repartitions, frames, frame_ms, work_ms,
efficiency_pipelined, frame_ms_pipelined, latency_ms, efficiency_worst, efficiency_together,
efficiency_together_worst, efficiency_sorted, efficiency_best, stagger_ms, frames_cancelled, t1_ms,
speedup, parallel_efficiency}, "meta": {...}}`` over the published frames after the first
``--skip`` (10) (:func:`bench.virtual_cluster.summarize`). ``efficiency`` scores each frame alone:
its ideal time (its work spread by node speed) over its slowest node's busy time on it;
``efficiency_worst`` is its worst frame's. ``efficiency_together``, ``efficiency_sorted``,
``efficiency_best`` and ``stagger_ms`` say where a frame's loss goes (:mod:`bench.rotation_loss`):
the same tiles pulled in the same order with every node starting the frame at once, the same sorted
by measured cost, the best split of those tiles, and how far after the first node the others began
the frame; ``--trace OUT`` writes each frame's tiles per node. ``efficiency_pipelined`` is the work
done between the last left-out frame's publication and the last but one's, as ideal time, over that
elapsed time: where a node done with its part of a frame starts on the next, it
is above ``efficiency``. ``frame_ms_pipelined`` is the mean interval between publications,
``latency_ms`` the mean time from a camera's input (the moment the frame before started) to its
frame's publication, ``frames_cancelled`` the frames the scheduler dropped. T1 (``t1_ms``) is one
speed-1 node rendering the whole frame (render + read-back + encode of the full screen, the same
timer), the mean over the kept frames' cameras; ``speedup`` = T1 / ``frame_ms_pipelined`` and
``parallel_efficiency`` = speedup / N: the figure a user compares with running one renderer,
per-tile redundancy included. With slowdowns the most a speedup can be is Σ 1/sᵢ (printed as the
ideal speedup). With ``--pace path`` the path's frame rate caps the speedup,
``efficiency_pipelined`` counts the nodes' wait for the next allowed start and ``latency_ms``
includes it.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bench.rotation_loss import frame_trace, rotation_loss
from bench.virtual_cluster import Phases, run_path, summarize
from node.culling.switch import CullMode
from tessera.balancers import BALANCERS, create_balancer
from tessera.balancers.base import BalanceInput, ProjectedGroups
from tessera.balancers.hetero import calibration_region, calibration_weights
from tessera.balancers.projection import posed_groups, project_groups
from tessera.balancers.static import StaticBalancer
from tessera.geometry import Camera, Rect
from tessera.scene.state import SceneState
from tessera.wire.codec import Codec, encode

DEFAULT_SKIP = 10
DEFAULT_IN_FLIGHT = 2
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


def parse_param(text: str) -> tuple[str, float | int | bool]:
    """``NAME=VALUE`` (``--param``) → (name, value): ``true``/``false`` a bool, a whole number an int,
    else a float (the balancer coerces it to its parameter's type)."""
    name, sep, value = text.partition("=")
    if not sep or not name.strip():
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}")
    lowered = value.strip().lower()
    if lowered in ("true", "false"):
        return name.strip(), lowered == "true"
    try:
        return name.strip(), int(lowered) if lowered.lstrip("+-").isdigit() else float(lowered)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{name.strip()}: expected a number, true or false, got {value!r}") from None


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


def frame_states(scene: Any, frames: int, time_per_frame: float | None,
                 start_time: float = 0.0) -> list[SceneState | None]:
    """Each frame's scene state: ``scene`` (a :class:`node.scene.data.SceneData`) at ``start_time``
    + i·``time_per_frame`` s for frame i; all None (the base pose) without ``time_per_frame``."""
    if time_per_frame is None:
        return [None] * frames
    return [scene.state_at(start_time + i * time_per_frame) for i in range(frames)]


def frame_groups(scene: Any, camera: Camera, size: tuple[int, int], state: SceneState | None) -> ProjectedGroups:
    """``scene``'s primitive groups projected for ``camera`` in ``state`` (None: the base pose), each
    moved with its object, with the near/far of the state's bounds, as the coordinator projects
    them (:meth:`tessera.scheduling.scheduler.FrameScheduler.set_groups`)."""
    groups = scene.groups
    if state is None:
        return project_groups(groups.boxes, groups.counts, camera, size, scene.bounds)
    seen = scene.objects.bounds(state)
    boxes, counts = posed_groups(groups.boxes, groups.counts, groups.owners, scene.objects, state)
    return project_groups(boxes, counts, camera, size, scene.bounds if seen is None else seen)


class TileTimer:
    """``measure(frame, rects)`` for :func:`bench.virtual_cluster.run_path` (frame: the camera's
    index in the path; drawn in ``states[frame]``, None: the base pose): renders a frame's tiles
    ``repeats`` times, interleaved (every tile once,
    then again), so that all of a frame's tiles are timed under the same machine conditions; keeps
    each phase's minimum; memoized per (frame, rect). ``cpu_clock``: a phase's time is the calling
    thread's CPU time (the renderer's wall-clock split between render and read-back scaled to it)
    — immune to preemption by other processes, exact when llvmpipe runs on the calling thread
    (LP_NUM_THREADS=0)."""

    def __init__(self, renderer: Any, cameras: Sequence[Camera], size: tuple[int, int], codec: Codec,
                 jpeg_quality: int, repeats: int, cpu_clock: bool = True, tolerance: float = 0.03,
                 max_repeats: int | None = None, states: Sequence[SceneState | None] | None = None) -> None:
        self.renderer, self.cameras, self.size = renderer, cameras, size
        self.states = list(states) if states is not None else [None] * len(cameras)
        self.codec, self.jpeg_quality, self.repeats, self.cpu_clock = codec, jpeg_quality, repeats, cpu_clock
        self.tolerance, self.max_repeats = tolerance, max(repeats, max_repeats or 3 * repeats)
        self.cache: dict[tuple[int, int, int, int, int], Phases] = {}
        self.renders = 0
        self.hits = 0

    def _once(self, camera: Camera, rect: Rect, encode_pixels: bool,
              state: SceneState | None) -> tuple[float, float, float]:
        """One render (+ encode) of ``rect`` in ``state``: render, read-back and encode ms."""
        cpu_started = time.thread_time()
        tile = self.renderer.render_tile(camera, self.size, rect, slot="bench", state=state)
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

    def time_rects(self, camera: Camera, rects: Sequence[Rect], encode_pixels: bool = True,
                   state: SceneState | None = None) -> list[Phases]:
        """Each rect's minimum render, read-back and encode ms (drawn in ``state``) over ``repeats`` interleaved rounds,
        then further rounds of the tiles whose two fastest busy times still differ by more than
        ``tolerance`` (at most ``max_repeats`` renders of a tile)."""
        samples: list[list[tuple[float, float, float]]] = [[] for _ in rects]
        pending = list(range(len(rects)))
        while pending:
            for i in pending:
                samples[i].append(self._once(camera, rects[i], encode_pixels, state))
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
        timed = self.time_rects(self.cameras[frame], list(missing.values()), state=self.states[frame])
        self.cache.update(zip(missing, timed, strict=True))
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
    flight = parser.add_mutually_exclusive_group()
    flight.add_argument("--in-flight", type=int,
                        help=f"frames in flight at most (default {DEFAULT_IN_FLIGHT}, as the live coordinator)")
    flight.add_argument("--lag", type=int,
                        help="the old form of --in-flight: --lag L means --in-flight L+1 (--lag 1 = 2 in flight)")
    parser.add_argument("--pace", choices=("free", "path"), default="free",
                        help="free (default): frames as fast as the cluster goes; path: frame starts at most "
                             "1000/dt_ms per second, the path's rate")
    parser.add_argument("--repeats", type=int, default=3, help="renders per tile; each phase's minimum is kept")
    parser.add_argument("--frames", type=int, help="run only the path's first FRAMES cameras")
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
    parser.add_argument("--time-per-frame", type=float, metavar="S",
                        help="play the scene's animation along the path: camera i at --start-time + i*S s")
    parser.add_argument("--start-time", type=float, default=0.0, metavar="T", help="scene time of camera 0 (s)")
    parser.add_argument("--param", type=parse_param, action="append", default=[], metavar="NAME=VALUE",
                        help="a balancer parameter (repeatable), given to each chosen balancer that has it: "
                             "--param tiles_per_node=4")
    parser.add_argument("--json", type=Path, help="write the figures here")
    parser.add_argument("--trace", type=Path,
                        help="write every frame here, a JSON line each: per node when it began and ended its tiles "
                             "of the frame, its busy time and each tile's")
    return parser


def check_args(parser: argparse.ArgumentParser, args: argparse.Namespace) -> list[str]:
    """The balancer names; sets ``args.in_flight`` from ``--lag``; exits through ``parser.error`` on
    bad arguments."""
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
    if args.lag is not None and args.lag < 0:
        parser.error("--lag must be >= 0")
    if args.in_flight is None:
        args.in_flight = DEFAULT_IN_FLIGHT if args.lag is None else args.lag + 1
    if args.in_flight < 1:
        parser.error("--in-flight must be >= 1")
    given = dict(args.param)
    unused = sorted(set(given) - {key for name in names for key in BALANCERS[name].defaults})
    if unused:
        parser.error(f"no balancer of {', '.join(names)} takes {', '.join(unused)}")
    args.balancer_params = {name: {k: v for k, v in given.items() if k in BALANCERS[name].defaults} for name in names}
    return names


def pace_fps(pace: str, dt_ms: float) -> float:
    """The scheduler's frame-start cap (frames/s): unbounded for ``free``, the path's 1000 / dt_ms for
    ``path``."""
    return 1000.0 / dt_ms if pace == "path" else math.inf


def single_node_ms(timer: TileTimer, frames: Iterable[int]) -> float:
    """T1: the mean busy ms (render + read-back + encode) of one speed-1 node rendering each of
    ``frames`` (camera indices) whole, through ``timer``."""
    screen = [Rect(0, 0, *timer.size)]
    return float(np.mean([timer(frame, screen)[0].busy_ms for frame in frames]))


def speedup_figures(t1_ms: float, frame_ms: float, nodes: int) -> dict[str, float]:
    """T1 (ms) against the cluster's frame interval ``frame_ms``: ``t1_ms``, ``speedup`` = T1 /
    frame_ms and ``parallel_efficiency`` = speedup / ``nodes`` (NaN when frame_ms is)."""
    speedup = t1_ms / frame_ms
    return {"t1_ms": t1_ms, "speedup": speedup, "parallel_efficiency": speedup / nodes}


def ideal_speedup(slowdowns: Iterable[float]) -> float:
    """The most nodes of slowdowns sᵢ can speed a frame up over one speed-1 node: Σ 1/sᵢ."""
    return sum(1.0 / s for s in slowdowns)


#: table columns: JSON key → heading
TABLE_COLUMNS = {"imbalance_mean": "imbalance_mean", "imbalance_p95": "imbalance_p95", "efficiency": "efficiency",
                 "efficiency_worst": "eff_worst", "efficiency_together": "eff_together",
                 "efficiency_sorted": "eff_sorted", "efficiency_best": "eff_best", "stagger_ms": "stagger_ms",
                 "efficiency_pipelined": "efficiency_pipe", "repartitions": "repartitions", "frames": "frames",
                 "frames_cancelled": "cancelled", "frame_ms": "frame_ms", "frame_ms_pipelined": "frame_ms_pipe",
                 "work_ms": "work_ms", "latency_ms": "latency_ms", "t1_ms": "t1_ms", "speedup": "speedup",
                 "parallel_efficiency": "parallel_eff"}


def format_table(results: dict[str, dict[str, float | int]]) -> str:
    width = max(len("balancer"), *(len(n) for n in results))
    widths = {key: max(len(heading), 8) for key, heading in TABLE_COLUMNS.items()}
    lines = [f"{'balancer':<{width}}  " + "  ".join(f"{h:>{widths[k]}}" for k, h in TABLE_COLUMNS.items())]
    for name, row in results.items():
        cells = [f"{row[k]:>{widths[k]}d}" if isinstance(row[k], int) else f"{row[k]:>{widths[k]}.3f}"
                 for k in TABLE_COLUMNS]
        lines.append(f"{name:<{width}}  " + "  ".join(cells))
    return "\n".join(lines)


def noise_check(timer: TileTimer, rects: Sequence[Rect], frames: int) -> dict[str, float]:
    """Re-time the tiles ``rects`` of every frame once more (the first timing from the memo, so
    the same as a balancer saw) and compare: mean and max change of a frame's max/mean over the
    tiles, median relative change of a tile's busy time."""
    changes, relative = [], []
    for frame in range(frames):
        first = np.array([p.busy_ms for p in timer(frame, rects)])
        second = np.array([p.busy_ms for p in timer.time_rects(timer.cameras[frame], rects,
                                                                state=timer.states[frame])])
        changes.append(abs(first.max() / first.mean() - second.max() / second.mean()))
        relative.extend(np.abs(second - first) / first)
    return {"imbalance_change_mean": float(np.mean(changes)), "imbalance_change_max": float(np.max(changes)),
            "tile_change_median": float(np.median(relative))}


def header_lines(args: argparse.Namespace, scene: Any, cameras: Sequence[Camera], dt_ms: float,
                 slowdowns: dict[int, float], weights: dict[int, float], calibration_ms: float, t1_ms: float,
                 renderer_name: str) -> list[str]:
    speeds = ",".join(f"{s:g}" for s in slowdowns.values())
    quality = f" q{args.jpeg_quality}" if args.codec is Codec.JPEG else ""
    pace = ("as fast as the cluster goes" if args.pace == "free"
            else f"frame starts at most {pace_fps(args.pace, dt_ms):g} per second (the path's dt)")
    return [
        "Tessera balancing benchmark: the coordinator's frame scheduler on a virtual clock, every tile rendered",
        f"  scene     {args.scene} ({scene.triangle_count} triangles, {len(scene.groups.counts)} primitive groups)",
        f"  path      {args.path}: {len(cameras)} frames, dt {dt_ms:g} ms; figures over frames "
        f"{args.skip}..{len(cameras) - 1}",
        f"  nodes     {args.nodes} at {args.size[0]}x{args.size[1]}; speeds {speeds} are slowdown factors: node i's "
        "measured times × sᵢ (2 = twice as slow, as node --slowdown)",
        f"  weights   calibration region {calibration_region(args.size).as_list()} {calibration_ms:.2f} ms × sᵢ → "
        + ", ".join(f"{n}: {w:.3f}" for n, w in weights.items()),
        f"  schedule  tessera.scheduling.scheduler.FrameScheduler, {args.in_flight} frame(s) in flight"
        + (" (as the live coordinator)" if args.in_flight == 2 else "")
        + f"; a frame starts when a node is free, with the newest camera, partitioned with the newest complete "
        f"frame's timings; every camera rendered once, {pace}",
        f"  T1        one speed-1 node rendering the whole frame: {t1_ms:.2f} ms (mean over frames {args.skip}.."
        f"{len(cameras) - 1}); speedup = T1 / frame_ms_pipe, parallel_eff = speedup / {args.nodes}; "
        f"ideal speedup Σ 1/sᵢ = {ideal_speedup(slowdowns.values()):.3g}",
        f"  noise     tiles rendered one at a time in one GL context; LP_NUM_THREADS={args.lp_threads} set before "
        f"it; clock: {'rendering thread CPU time' if args.clock == 'cpu' else 'wall'}; a frame's tiles timed in "
        f"interleaved rounds, each phase the minimum of >= {args.repeats} renders (more until the two fastest agree "
        f"within {TOLERANCE:.0%}, at most {3 * args.repeats}); memoized per (frame, rect)",
        f"  busy      render + readback + encode ({args.codec.name.lower()}{quality}); send not modelled; "
        f"culling {args.culling}",
        f"  renderer  {renderer_name}",
        *([] if args.time_per_frame is None else [
            f"  animation played along the path: camera i at scene time {args.start_time:g} + i × "
            f"{args.time_per_frame:g} s ({len(scene.objects)} objects); groups moved with their objects"]),
    ]


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    names = check_args(parser, args)
    dt_ms, cameras = load_path(args.path, args.frames)
    if len(cameras) <= args.skip:
        parser.error(f"the path has {len(cameras)} frames; the figures need more than --skip {args.skip}")
    os.environ["LP_NUM_THREADS"] = str(args.lp_threads)
    from node.gl.context import create_gl_context, renderer_string
    from node.gl.renderer import TileRenderer
    from node.scene.loading import load_scene

    started = time.perf_counter()
    scene = load_scene(args.scene)
    ctx = create_gl_context()
    renderer = TileRenderer(ctx, scene, culling=CullMode(args.culling))
    size = args.size
    states = frame_states(scene, len(cameras), args.time_per_frame, args.start_time)
    timer = TileTimer(renderer, cameras, size, args.codec, args.jpeg_quality, args.repeats, args.clock == "cpu",
                      TOLERANCE, states=states)
    timer.time_rects(cameras[0], [Rect(0, 0, *size)], state=states[0])  # warm-up: shader compilation, first touch
    node_ids = list(range(1, args.nodes + 1))
    slowdowns = dict(zip(node_ids, args.speeds or [1.0] * args.nodes, strict=True))
    calibration_ms = timer.time_rects(cameras[0], [calibration_region(size)], encode_pixels=False,
                                      state=states[0])[0].busy_ms
    weights = calibration_weights({n: calibration_ms * s for n, s in slowdowns.items()})
    path_t1_ms = single_node_ms(timer, range(args.skip, len(cameras)))
    groups = [frame_groups(scene, camera, size, state) for camera, state in zip(cameras, states, strict=True)]
    renderer_name = renderer_string(ctx)
    print("\n".join(header_lines(args, scene, cameras, dt_ms, slowdowns, weights, calibration_ms, path_t1_ms,
                                 renderer_name)), flush=True)

    results: dict[str, dict[str, float | int]] = {}
    traces: list[dict[str, object]] = []
    for name in names:
        balancer_started, renders_before = time.perf_counter(), timer.renders
        balancer = create_balancer(name, args.balancer_params[name])
        records, cluster = run_path(balancer, timer, cameras, size, slowdowns, weights, args.in_flight,
                                    groups.__getitem__, pace_fps(args.pace, dt_ms))
        summary = summarize(records, args.skip)
        t1_ms = single_node_ms(timer, [r.camera for r in records[args.skip:]])
        row = results[name] = {**summary, **rotation_loss(records, slowdowns, args.skip),
                               "frames_cancelled": cluster.scheduler.frames_cancelled,
                               **speedup_figures(t1_ms, summary["frame_ms_pipelined"], args.nodes)}
        if args.trace:
            traces.extend({"balancer": name, **frame_trace(r)} for r in records)
        print(f"  [{name}] {len(records)} frames in {time.perf_counter() - balancer_started:.1f} s, "
              f"{timer.renders - renders_before} renders (memo {len(timer.cache)} tiles, {timer.hits} hits); "
              f"imbalance_mean {row['imbalance_mean']:.3f}, efficiency {row['efficiency']:.3f}, "
              f"pipelined {row['efficiency_pipelined']:.3f}, speedup {row['speedup']:.2f}", flush=True)
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
    if args.trace:
        args.trace.parent.mkdir(parents=True, exist_ok=True)
        args.trace.write_text("".join(json.dumps(t) + "\n" for t in traces))
        print(f"wrote {args.trace}")
    if args.json:
        meta = {"scene": args.scene, "path": str(args.path), "frames": len(cameras), "dt_ms": dt_ms,
                "skip": args.skip, "nodes": args.nodes, "size": list(size), "speeds": list(slowdowns.values()),
                "speeds_meaning": "slowdown factors: node i's measured times are multiplied by s_i",
                "weights": {str(n): w for n, w in weights.items()}, "calibration_ms": calibration_ms,
                "lag": args.in_flight - 1, "in_flight": args.in_flight, "pace": args.pace,
                "max_fps": None if args.pace == "free" else pace_fps(args.pace, dt_ms),
                "t1_ms": path_t1_ms, "ideal_speedup": ideal_speedup(slowdowns.values()), "repeats": args.repeats,
                "tolerance": TOLERANCE, "lp_num_threads": args.lp_threads,
                "clock": args.clock, "culling": args.culling, "codec": args.codec.name.lower(),
                "jpeg_quality": args.jpeg_quality, "renderer": renderer_name, "noise": noise,
                "balancer_params": args.balancer_params,
                "time_per_frame": args.time_per_frame, "start_time": args.start_time,
                "renders": timer.renders, "seconds": round(total_s, 1), "python": platform.python_version(),
                "argv": sys.argv[1:] if argv is None else list(argv)}
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({**results, "meta": meta}, indent=2) + "\n")
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
