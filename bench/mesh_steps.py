"""A simulation pushing a new mesh every step through the Python client (issue 33): how many steps a
second reach the screen, and whether each one does.

``python -m bench.mesh_steps [--nodes 2] [--triangles 100000] [--rate 10] [--steps 20] [--size 640x360]
[--via update|upload|both] [--turn-s 4] [--json OUT]``

A height field of ``--triangles`` triangles (a wave moving a step each time) is pushed at most
``--rate`` times a second, ``--via update`` (default) with ``Session.update_mesh`` (binary arrays, no
library), ``--via upload`` uploaded as arrays (a GLB written in memory) and shown with
``Session.set_scene``; ``both`` runs one then the other on the same coordinator.
A second connection reads the session's frames as they are published (``Session.frames``) and
sorts each into the step it shows (its frame id at or after that step's first frame id, before the
next step's). Figures: steps per second pushed, the share of steps that reached a published frame,
each update's time, or the upload's (the GLB written in memory, sent, checked by the coordinator)
and the switch's.
The steps start once the coordinator is at rest (its default session's still is done).
Steps per second: the steps shown after the first over the time from the first one on screen (its
first frame read) to the last one; ``steps_per_s_from_start`` counts from the first step's start
instead, which adds one step's latency (``latency_s``: from its call to its first frame read). Then
the camera turns about the last step for ``--turn-s`` seconds: the frames per second published
meanwhile are the most steps a second could reach on this machine (a frame each), and
``of_frame_rate`` the share of it the steps reached.
"""

from __future__ import annotations

import argparse
import bisect
import math
import os
import statistics
import tempfile
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bench.processes import show_result, start_coordinator
from tessera.cli_values import size_parser
from tessera.client import Tessera, TesseraError


def height_field(triangles: int) -> tuple[np.ndarray, np.ndarray]:
    """(x, z grid (n+1)², faces (2n², 3)) of a square of about ``triangles`` triangles."""
    n = max(1, round(math.sqrt(triangles / 2)))
    xs, zs = np.meshgrid(np.linspace(-1, 1, n + 1), np.linspace(-1, 1, n + 1))
    index = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = index[:-1, :-1].ravel(), index[:-1, 1:].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, c, b], 1), np.stack([b, c, d], 1)])
    return np.stack([xs.ravel(), np.zeros(xs.size), zs.ravel()], 1), faces


def wave(grid: np.ndarray, t: float) -> np.ndarray:
    """The grid's vertices (N, 3) lifted by a ring wave at time ``t``."""
    vertices = grid.copy()
    vertices[:, 1] = 0.15 * np.sin(6 * np.hypot(grid[:, 0], grid[:, 2]) - 4 * t)
    return vertices


class FrameLog:
    """Frame ids the session publishes, and when each was read (monotonic s), on a thread of its own
    until stopped."""

    def __init__(self, session: Any) -> None:
        self.ids: list[int] = []
        self.times: list[float] = []
        self.error: str | None = None
        self._frames = session.frames(timeout=60.0)
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self) -> None:
        try:
            for frame_id, _ in self._frames:
                self.times.append(time.monotonic())
                self.ids.append(frame_id)
        except TesseraError as exc:
            self.error = exc.reason


def push_steps(tessera: Any, reader: Any, args: argparse.Namespace, via: str, grid: np.ndarray,
               faces: np.ndarray) -> dict[str, Any]:
    """Push ``args.steps`` steps through ``via`` ("update": ``Session.update_mesh``; "upload":
    ``upload`` then ``set_scene``) in a session of its own; the figures of that run."""
    camera = {"eye": [2.0, 1.5, 2.0], "target": [0, 0, 0], "up": [0, 1, 0], "fovy_deg": 45}
    if via == "update":
        session = tessera.open_session("builtin:cluster", size=args.size, camera=camera)
        session.update_mesh(wave(grid, 0.0), faces)
    else:
        session = tessera.open_session(tessera.upload((wave(grid, 0.0), faces)), size=args.size, camera=camera)
    steps: list[dict[str, float]] = []
    with session:
        session.snapshot(still=False)
        log = FrameLog(reader.session(session.id))
        started = time.monotonic()
        for step in range(args.steps):
            due = started + step / args.rate
            time.sleep(max(0.0, due - time.monotonic()))
            begin = time.monotonic()
            vertices = wave(grid, 0.1 * (step + 1))
            if via == "update":
                first = session.update_mesh(vertices, faces)
                steps.append({"first": first, "begin": begin, "update_s": time.monotonic() - begin})
            else:
                name = tessera.upload((vertices, faces))
                uploaded = time.monotonic()
                first = session.set_scene(name)
                steps.append({"first": first, "begin": begin, "upload_s": uploaded - begin,
                              "switch_s": time.monotonic() - uploaded})
        final_id, _ = session.snapshot_frame(still=False, after=steps[-1]["first"])
        shown_at = time.monotonic()
        elapsed = shown_at - started   # from the first step's start to the last step on screen
        while not log.ids or log.ids[-1] < final_id:
            if time.monotonic() - shown_at > 30.0:
                break
            time.sleep(0.05)
        read = sorted(zip(log.ids, log.times, strict=False))   # the reader may be a frame ahead in one
        ids, reader_error = [frame_id for frame_id, _ in read], log.error
        frame_rate = turning_rate(session, log, args.turn_s)
    firsts = [int(s["first"]) for s in steps]
    on_screen_at: list[float] = []   # when each step shown was first on screen (its first frame read)
    for index, first in enumerate(firsts):
        end = firsts[index + 1] if index + 1 < len(firsts) else math.inf
        at = bisect.bisect_left(ids, first)
        if at < len(ids) and ids[at] < end:
            on_screen_at.append(read[at][1])
            steps[index]["latency_s"] = read[at][1] - steps[index]["begin"]
    shown = len(on_screen_at)
    on_screen = on_screen_at[-1] - on_screen_at[0] if shown > 1 else 0.0

    def quantiles(values: list[float]) -> dict[str, float]:
        ordered = sorted(values)
        return {"p50": statistics.median(ordered), "p90": ordered[min(len(ordered) - 1, int(0.9 * len(ordered)))]}

    times = {key: quantiles([s[key] for s in steps if key in s])
             for key in ("update_s", "upload_s", "switch_s", "latency_s") if any(key in s for s in steps)}
    rate = (shown - 1) / on_screen if on_screen > 0 else None
    return {"via": via, "triangles": len(faces), "rate": args.rate, "steps": args.steps, "size": list(args.size),
            "nodes": args.nodes, "steps_per_s": rate, "steps_per_s_from_start": (args.steps - 1) / elapsed,
            "frames_per_s_turning": frame_rate,
            "of_frame_rate": rate / frame_rate if frame_rate and rate else None, "steps_shown": shown,
            "shown_share": shown / len(steps), "frames_seen": len(ids), **times, "reader_error": reader_error}


def turning_rate(session: Any, log: FrameLog, seconds: float) -> float | None:
    """Frames a second ``log`` saw published while the camera turned a degree every 20 ms for
    ``seconds`` (the first half second not counted); None for 0 s."""
    if seconds <= 0:
        return None
    started = time.monotonic()
    counted, count = None, 0
    while (now := time.monotonic()) < started + seconds:
        if counted is None and now >= started + 0.5:
            counted, count = now, len(log.ids)
        session.orbit(1.0)
        time.sleep(0.02)
    return None if counted is None else (len(log.ids) - count) / (time.monotonic() - counted)


def measure(args: argparse.Namespace) -> dict[str, Any]:
    """Every mode of ``args.via`` on one coordinator with ``args.nodes`` local nodes: one run's
    figures at the top level, several runs' in ``runs``."""
    data = tempfile.TemporaryDirectory(prefix="tessera-bench-mesh-steps-")   # the uploads, removed after
    coordinator, url = start_coordinator(["--local-nodes", str(args.nodes), "--size", "160x90", "--data-dir",
                                          data.name], timeout=120.0)
    grid, faces = height_field(args.triangles)
    modes = ["update", "upload"] if args.via == "both" else [args.via]
    try:
        with Tessera(url) as tessera, Tessera(url) as reader:
            tessera.session("default").snapshot(still=True)   # at rest: the default session's still is done
            runs = [push_steps(tessera, reader, args, via, grid, faces) for via in modes]
    finally:
        coordinator.stop()
        data.cleanup()
    result: dict[str, Any] = {"benchmark": "mesh_steps", **(runs[0] if len(runs) == 1 else {"runs": runs}),
                              "load_average": os.getloadavg()}
    return result


def report(result: dict[str, Any]) -> str:
    lines = []
    for run in result.get("runs", [result]):
        times = (f"update_mesh (checked, sent as arrays) p50 {run['update_s']['p50']:.3f} s, "
                 f"p90 {run['update_s']['p90']:.3f} s" if run["via"] == "update" else
                 f"upload (GLB in memory, send, the coordinator's check) p50 {run['upload_s']['p50']:.3f} s, "
                 f"p90 {run['upload_s']['p90']:.3f} s; set_scene p50 {run['switch_s']['p50']:.3f} s")
        latency = run.get("latency_s")
        lines += [
            f"via {run['via']}: {run['triangles']} triangles a step, asked {run['rate']:g} steps/s, {run['steps']} "
            f"steps, {run['size'][0]}x{run['size'][1]}, {run['nodes']} local nodes",
            f"  steps/s reached: {run['steps_per_s'] or 0:.2f} ({run['steps_per_s_from_start']:.2f} from the first "
            f"step's start)" + (f"; a step's latency p50 {latency['p50']:.3f} s, p90 {latency['p90']:.3f} s"
                                if latency else "") + f"; steps shown: {run['steps_shown']} of {run['steps']} "
            f"({100 * run['shown_share']:.0f} %); frames published: {run['frames_seen']}",
            *([f"  frames/s while the camera turns about the last step: {run['frames_per_s_turning']:.2f} "
               f"(the steps reached {100 * (run['of_frame_rate'] or 0):.0f} % of it)"]
              if run["frames_per_s_turning"] else []),
            f"  {times}"]
    lines.append("load average (1, 5, 15 min) at the end: " + ", ".join(f"{v:.2f}" for v in result["load_average"]))
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m bench.mesh_steps", description=__doc__.splitlines()[0])
    parser.add_argument("--nodes", type=int, default=2, help="local render nodes (default 2)")
    parser.add_argument("--triangles", type=int, default=100_000, help="triangles of each step's mesh (100000)")
    parser.add_argument("--rate", type=float, default=10.0, help="steps per second asked for (default 10)")
    parser.add_argument("--steps", type=int, default=20, help="steps pushed (default 20)")
    parser.add_argument("--size", type=size_parser(16, 4096), default=(640, 360), help="frame size WxH (640x360)")
    parser.add_argument("--via", choices=("update", "upload", "both"), default="update",
                        help="update: Session.update_mesh (default); upload: upload then set_scene; both, in turn")
    parser.add_argument("--turn-s", type=float, default=4.0,
                        help="seconds the camera turns about the last step, for the frame rate (default 4; 0: none)")
    parser.add_argument("--json", type=Path, help="write the result as JSON here")
    return parser


def main(argv: Sequence[str] | None = None) -> None:
    args = build_parser().parse_args(argv)
    result = measure(args)
    show_result(report(result), result, args.json, argv)


if __name__ == "__main__":
    main()
