"""``python -m bench.frozen``: a node frozen with SIGSTOP while a viewer turns the camera, then thawed.

A coordinator and ``--nodes`` render nodes (3 by default), each a process of its own, started and
watched by :mod:`bench.soak`'s machinery, and one persistent viewer turning the camera over its
socket and recording when each frame arrives. Once every node renders, ``--freezes`` times the next
node in turn gets SIGSTOP (it keeps its socket open and answers nothing: a hung process, not a
crash), stays stopped ``--freeze-s`` seconds, gets SIGCONT, and the run goes on ``--between-s``
seconds before the next freeze. The viewer socket is the user's view: each figure is about frames
arriving there.

Per freeze it reports

* **gap during the freeze**: the longest gap between frames on the viewer that touches the frozen
  interval (SIGSTOP → SIGCONT; the gap spanning SIGSTOP counts in full), and the frames/s then;
* **detection**: SIGSTOP → the node listed ``suspect`` in ``/api/stats`` (polled every 50 ms),
  when the scheduler backs its tiles up to the other nodes;
* **rejoin**: SIGCONT → the node not suspect and its ``tiles_rendered`` (tiles of frames still in
  flight that it delivered first) above its count at SIGCONT: it renders for the frames again;
* **gap after**: the longest gap from SIGCONT until the next SIGSTOP (``--between-s`` later) or the
  end (a gap running into the next freeze counts there), and the frames/s then;

with the longest gap before the first freeze as the baseline, and the goals: gap during every
freeze ≤ 1 s, every frozen node rejoined, no frame out of order, no crash. Bounded: every wait has
a deadline, a frozen node is sent SIGCONT on every way out, and every process is stopped.
"""

from __future__ import annotations

import argparse
import itertools
import math
import os
import signal
import sys
import time
from collections.abc import Sequence
from typing import Any

import httpx

from bench.soak import GAP_GOAL_S, REJOIN_TIMEOUT_S, PersistentViewer, Soak, run_bench, run_parser

POLL_S = 0.05
FIRST_TILES_TIMEOUT_S = 60.0


def longest_gap(times: Sequence[float], start: float, end: float, spanning_end: bool = True) -> tuple[float, float]:
    """The longest gap between consecutive ``times`` (sorted) that overlaps [start, end], and when it
    began; times before and after the interval bound the gaps over its edges. ``spanning_end``
    False leaves out a gap running past ``end`` (it belongs to what begins there)."""
    best = (0.0, math.nan)
    for a, b in itertools.pairwise(times):
        if a < end and b > start and (spanning_end or b <= end) and b - a > best[0]:
            best = (b - a, a)
    return best


def node_stats(soak: Soak, client: httpx.Client, name: str) -> dict[str, Any] | None:
    """The node called ``name`` in /api/stats (None: not listed, or the request failed)."""
    try:
        return next((n for n in soak.stats(client)["nodes"] if n["name"] == name), None)
    except httpx.HTTPError:
        return None


def poll_until(condition: Any, deadline: float) -> float | None:
    """Call ``condition`` every POLL_S until it is true (the time it was) or ``deadline`` (None)."""
    while (now := time.monotonic()) < deadline:
        if condition():
            return now
        time.sleep(POLL_S)
    return None


def freeze_once(soak: Soak, client: httpx.Client, slot: int, freeze_s: float) -> dict[str, Any]:
    """SIGSTOP node ``slot`` for ``freeze_s`` s, SIGCONT, wait for it to render again (bounded)."""
    node = soak.nodes[slot]
    record: dict[str, Any] = {"node": node.label, "stopped": time.monotonic(), "suspected": None, "rejoined": None}
    last: dict[str, Any] | None = None
    os.kill(node.pid, signal.SIGSTOP)
    try:
        thaw_at = record["stopped"] + freeze_s
        record["suspected"] = poll_until(lambda: (n := node_stats(soak, client, node.label)) is not None
                                         and n["suspect"], thaw_at)
        time.sleep(max(0.0, thaw_at - POLL_S - time.monotonic()))
        last = node_stats(soak, client, node.label)  # its count while stopped, just before SIGCONT
        time.sleep(max(0.0, thaw_at - time.monotonic()))
    finally:
        os.kill(node.pid, signal.SIGCONT)
        record["continued"] = time.monotonic()
    record["suspect_at_sigcont"] = bool(last and last["suspect"])
    rendered = last["tiles_rendered"] if last is not None else 0
    record["rejoined"] = poll_until(lambda: (n := node_stats(soak, client, node.label)) is not None
                                    and not n["suspect"] and n["tiles_rendered"] > rendered,
                                    record["continued"] + REJOIN_TIMEOUT_S)
    return record


def drive(soak: Soak) -> dict[str, Any]:
    """Start everything, freeze the nodes in turn, stop the viewer; what was recorded."""
    args = soak.args
    launched = time.monotonic()
    with soak.cluster(launched) as (client, viewer):
        freezes: list[dict[str, Any]] = []
        try:
            if poll_until(lambda: all(n["tiles_rendered"] > 0 for n in soak.stats(client)["nodes"]),
                          time.monotonic() + FIRST_TILES_TIMEOUT_S) is None:
                raise RuntimeError(f"not every node rendered a tile within {FIRST_TILES_TIMEOUT_S:.0f} s")
            t0 = time.monotonic()
            time.sleep(args.between_s)
            for index in range(args.freezes):
                record = freeze_once(soak, client, index % args.nodes, args.freeze_s)
                freezes.append(record)
                # the run goes on --between-s after SIGCONT, longer only while the node has not rejoined
                time.sleep(max(0.0, record["continued"] + args.between_s - time.monotonic()))
                if soak.coordinator is not None and soak.coordinator.process.poll() is not None:
                    break
            t_end = time.monotonic()
        finally:
            viewer.stop()
    return {"t0": t0, "t_end": t_end, "viewer": viewer, "freezes": freezes}


def figures(soak: Soak, run: dict[str, Any]) -> dict[str, Any]:
    args, t0, t_end = soak.args, run["t0"], run["t_end"]
    viewer: PersistentViewer = run["viewer"]
    times = [t0, *(t for t, _ in viewer.arrivals if t0 <= t <= t_end), t_end]

    def frames_in(start: float, end: float) -> int:
        return sum(start <= t <= end for t, _ in viewer.arrivals)

    freezes = []
    stops = [f["stopped"] for f in run["freezes"]]
    for f, after_end in zip(run["freezes"], [*stops[1:], t_end], strict=True):
        stop, cont = f["stopped"], f["continued"]
        during, during_at = longest_gap(times, stop, cont)
        after, after_at = longest_gap(times, cont, after_end, spanning_end=False)
        freezes.append({
            "node": f["node"], "at_s": stop - t0, "frozen_s": cont - stop,
            "detected_s": None if f["suspected"] is None else f["suspected"] - stop,
            "longest_gap_frozen_s": during, "longest_gap_frozen_at_s": during_at - t0,
            "fps_frozen": frames_in(stop, cont) / (cont - stop),
            "suspect_at_sigcont": f["suspect_at_sigcont"],
            "rejoin_s": None if f["rejoined"] is None else f["rejoined"] - cont,
            "longest_gap_after_s": after, "longest_gap_after_at_s": after_at - t0,
            "fps_after": frames_in(cont, after_end) / max(after_end - cont, 1e-9),
        })
    baseline, _ = longest_gap(times, t0, stops[0] if stops else t_end, spanning_end=False)
    unclean = {label: e for label, e in soak.exits.items() if e["returncode"] != 0 or e["killed"]}
    tracebacks = {label: e["tracebacks"] for label, e in soak.exits.items() if e["tracebacks"]}
    frames = [a for a in viewer.arrivals if t0 <= a[0] <= t_end]
    worst = max((f["longest_gap_frozen_s"] for f in freezes), default=math.nan)
    result: dict[str, Any] = {
        "nodes": args.nodes, "scene": args.scene, "size": list(args.size), "freeze_s": args.freeze_s,
        "between_s": args.between_s, "camera_hz": args.camera_hz, "run_s": t_end - t0,
        "frames_received": len(frames), "fps": len(frames) / max(t_end - t0, 1e-9),
        "frames_backwards": viewer.backwards,
        "viewer_drops": [{"at_s": t - t0, "why": why} for t, why in viewer.drops],
        "longest_gap_before_s": baseline, "longest_gap_frozen_s": worst,
        "longest_gap_after_s": max((f["longest_gap_after_s"] for f in freezes), default=math.nan),
        "freezes": freezes, "crashes": soak.crashes, "exits": soak.exits, "unclean_exits": unclean,
        "tracebacks": tracebacks, "log_dir": str(soak.log_dir),
    }
    result["goals"] = {
        "gap_frozen_le_1s": bool(freezes) and worst <= GAP_GOAL_S,
        "every_frozen_node_rejoined": bool(freezes) and all(f["rejoin_s"] is not None for f in freezes),
        "frames_in_order": viewer.backwards == 0 and not viewer.drops,
        "no_crash": not unclean and not tracebacks and len(freezes) == args.freezes,
    }
    return result


def report(result: dict[str, Any]) -> str:
    def s(value: float | None) -> str:
        return "never" if value is None else f"{value:.2f} s"

    size = result["size"]
    lines = [f"Tessera frozen node: {result['nodes']} nodes, {result['scene']} at {size[0]}x{size[1]}, "
             f"{len(result['freezes'])} freezes of {result['freeze_s']:g} s (SIGSTOP → SIGCONT), camera turning; "
             f"{result['frames_received']} frames in {result['run_s']:.0f} s ({result['fps']:.1f} fps)",
             f"  longest gap before the first freeze {result['longest_gap_before_s']:.2f} s",
             f"  {'node':<10}{'detected':>10}{'gap frozen':>12}{'fps frozen':>12}{'rejoin':>10}{'gap after':>11}"
             f"{'fps after':>11}"]
    for f in result["freezes"]:
        lines.append(f"  {f['node']:<10}{s(f['detected_s']):>10}{f['longest_gap_frozen_s']:>10.2f} s"
                     f"{f['fps_frozen']:>12.1f}{s(f['rejoin_s']):>10}{f['longest_gap_after_s']:>9.2f} s"
                     f"{f['fps_after']:>11.1f}")
    lines += [
        f"  frames          {result['frames_backwards']} out of order, {len(result['viewer_drops'])} drops "
        "of the viewer's socket",
        f"  crashes         {len(result['unclean_exits'])} unclean stops, tracebacks {result['tracebacks'] or 'none'}",
        "  goals           " + ", ".join(f"{name} {'yes' if ok else 'NO'}" for name, ok in result["goals"].items()),
        f"  logs            {result['log_dir']}",
    ]
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    parser = run_parser("python -m bench.frozen", __doc__.split("\n\n")[0], nodes=3)
    parser.add_argument("--freeze-s", type=float, default=5.0, help="seconds each node stays stopped (default 5)")
    parser.add_argument("--freezes", type=int, default=3, help="freezes, the nodes in turn (default 3)")
    parser.add_argument("--between-s", type=float, default=5.0,
                        help="seconds before the first freeze and after each SIGCONT (default 5)")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.nodes < 2 or args.freezes < 1 or not args.freeze_s > 0:
        raise SystemExit("--nodes must be at least 2 (one frozen, one to take over), --freezes ≥ 1, --freeze-s > 0")
    run_bench(args, "tessera-frozen-", drive, figures, report, argv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
