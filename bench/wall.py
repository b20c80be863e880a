"""A display wall (issue 22): a C × R wall session whose cells are frame-locked viewers, against
one session of the same total size.

``python -m bench.wall --cols 2 --rows 2 --cell 640x360 [--bezel 0x0] [--nodes 3]
[--scene builtin:cluster] [--input-hz 30] [--moving-s 8] [--turn-s 8] [--chromium] [--rounds 1]
[--server-args "…"] [--present-log LOG] [--json OUT]``

The wall: one viewer per cell (``/ws/view?session=ID&cell=C,R``) and a driver on the drive link that
turns the camera at ``--input-hz``. Cells are scripted viewers (a thread each that says ``have`` for
every frame, presents on ``present`` at its time and reports when, on the coordinator's clock
estimated by ping → pong), or with ``--chromium`` headless Chromium pages of the real viewer, each
page's viewport the cell's size as a screen of the wall would be (their present logs, web/wall.js,
say when each present came and which animation frame it was drawn in). Over the window (its first
second left out): frames the lock presented per second, frames the driver received per second, the
present skew between cells (p50, p99 in ms, from ``/api/sessions/{id}/stats``), the lead presents
were told with. The single session: one session of the wall's whole size moved the same way by one
viewer (with ``--chromium``, a Chromium page of the whole size watches it too: the same pixels on
screen as the cells'): frames per second. Their ratio is what the wall costs in throughput;
``--rounds`` alternates the two and takes medians. Each window says how many cores were busy: the
coordinator and its nodes, the scripted viewers, the browser, and other work on the machine; and the
CPU ms the coordinator and the nodes spent per frame made (medians over the rounds: the nodes' wall
/ single, the coordinator's extra ms a wall frame).

Everything shares this machine's cores: on 2 cores, N nodes, the cells and the coordinator take turns.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import shlex
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import websockets.sync.client as ws_client

from bench.live import ScriptedViewer, wait_ready
from bench.processes import CLOCK_TICKS, cpu_seconds, process_tree, show_result, start_coordinator
from bench.sessions import move, wait_session_ready
from tessera.cli_values import size_parser
from tessera.wire.protocol import unpack_frame

#: Pings a scripted cell sends first for its clock estimate, and how often it pings after (s).
FIRST_PINGS = 5
PING_S = 1.0
CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
                 "--disable-sync", "--no-first-run", "--disable-renderer-backgrounding",
                 "--disable-background-timer-throttling", "--disable-backgrounding-occluded-windows"]


class ScriptedCell:
    """One cell of the wall on an open ``/ws/view?…&cell=C,R`` connection: a thread says ``have``
    for every frame, presents on ``present`` at the time it names (a script has no display: it
    sleeps until then) and reports the time on the coordinator's clock, estimated from the
    ping → pong with the shortest round trip."""

    def __init__(self, ws: ws_client.ClientConnection) -> None:
        self.ws = ws
        self.offset_ms: float | None = None
        self._best_rtt = math.inf
        self.presented: list[int] = []
        self._stop = threading.Event()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _ping(self) -> None:
        self.ws.send(json.dumps({"type": "ping", "t0": time.perf_counter() * 1000.0}))

    def _read(self) -> None:
        for _ in range(FIRST_PINGS):
            self._ping()
        pinged = time.perf_counter()
        while not self._stop.is_set():
            if time.perf_counter() - pinged >= PING_S:
                self._ping()
                pinged = time.perf_counter()
            try:
                message = self.ws.recv(timeout=0.2)
            except TimeoutError:
                continue
            except Exception:
                return
            if isinstance(message, bytes):
                self.ws.send(json.dumps({"type": "have", "frame": unpack_frame(message).frame_id}))
                continue
            data = json.loads(message)
            now_ms = time.perf_counter() * 1000.0
            if data["type"] == "pong" and now_ms - data["t0"] < self._best_rtt:
                self._best_rtt = now_ms - data["t0"]
                self.offset_ms = data["clock_ms"] - (data["t0"] + now_ms) / 2
            elif data["type"] == "present" and self.offset_ms is not None:
                time.sleep(max(0.0, data["at_ms"] - self.offset_ms - now_ms) / 1000.0)
                self.presented.append(data["frame"])
                self.ws.send(json.dumps({"type": "presented", "frame": data["frame"],
                                         "at_ms": max(0.0, time.perf_counter() * 1000.0 + self.offset_ms)}))

    def stop(self) -> None:
        self._stop.set()
        self._reader.join(timeout=5)


@contextlib.contextmanager
def chromium() -> Iterator[Any]:
    """A headless Chromium browser (Playwright), open until the block ends."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        try:
            yield browser
        finally:
            browser.close()


@contextlib.contextmanager
def pages_at(browser: Any, urls: list[str], viewport: tuple[int, int]) -> Iterator[list[Any]]:
    """A page of the viewer at each of ``urls`` in ``browser``, ``viewport`` (w, h) CSS px each (the
    pages), closed when the block ends."""
    pages = [browser.new_page(viewport={"width": viewport[0], "height": viewport[1]}) for _ in urls]
    try:
        for page, url in zip(pages, urls, strict=True):
            page.goto(url)
        yield pages
    finally:
        for page in pages:
            page.close()


def machine_busy_s() -> tuple[float, float]:
    """This machine's CPU seconds busy (all cores, /proc/stat: not idle, not waiting) and its
    monotonic clock (s)."""
    with open("/proc/stat") as stat:
        fields = [int(v) for v in stat.readline().split()[1:]]
    return (sum(fields) - fields[3] - fields[4]) / CLOCK_TICKS, time.monotonic()


class CpuUse:
    """CPU seconds from here on: the coordinator (``service_pid``) and its nodes (the rest of its
    tree), this process (scripted cells and viewers), the rest of this process's tree (Playwright
    and Chromium), and the whole machine (everything else is other work on it)."""

    def __init__(self, service_pid: int) -> None:
        self.service_pid = service_pid
        self.start = self._read()

    def _read(self) -> dict[str, float]:
        service = process_tree(self.service_pid)
        ours = process_tree(os.getpid())
        busy, now = machine_busy_s()
        coordinator = cpu_seconds([self.service_pid])
        return {"coordinator": coordinator, "nodes": cpu_seconds(service) - coordinator,
                "bench": cpu_seconds([os.getpid()]),
                "browser": cpu_seconds([pid for pid in ours if pid not in service and pid != os.getpid()]),
                "machine": busy, "at": now}

    def cores(self) -> dict[str, float]:
        """Cores busy on average since this was made, by whom."""
        end = self._read()
        seconds = end["at"] - self.start["at"]
        keys = ("coordinator", "nodes", "bench", "browser")
        used = {key: (end[key] - self.start[key]) / seconds for key in (*keys, "machine")}
        used["other"] = used["machine"] - sum(used[key] for key in keys)
        return {key: round(value, 2) for key, value in used.items()}


def percentiles(values: list[float]) -> dict[str, float | None]:
    """p50, p99 and max of ``values`` (ms), None when there are none."""
    if not values:
        return {"p50": None, "p99": None, "max": None}
    array = np.asarray(values, dtype=np.float64)
    return {"p50": round(float(np.percentile(array, 50)), 2), "p99": round(float(np.percentile(array, 99)), 2),
            "max": round(float(array.max()), 2)}


def present_timing(logs: list[list[dict[str, Any]]], frames: set[int]) -> dict[str, Any]:
    """What the Chromium cells' Presenter logs (web/wall.js, one list per cell) say about the
    ``frames`` every cell presented, in ms: how long before its due time the present reached the
    page (negative: after it), the timestamp of the animation frame it was drawn in after the due
    time and how long after that timestamp the page's callback ran; per frame, the spread of the
    cells' timestamps on the coordinator's clock (the skew they report)."""
    by_cell = [{e["frame"]: e for e in log if e["frame"] in frames and e.get("due") is not None} for log in logs]
    common = set.intersection(*(set(cell) for cell in by_cell)) if by_cell else set()
    figures: dict[str, list[float]] = {"received_before_due": [], "ts_after_due": [], "callback_after_ts": []}
    for cell in by_cell:
        for entry in cell.values():
            figures["received_before_due"].append(entry["due"] - entry["received"])
            figures["ts_after_due"].append(entry["ts"] - entry["due"])
            figures["callback_after_ts"].append(entry["callback"] - entry["ts"])
    spread = []
    for frame in common:
        times = [cell[frame]["ts"] + cell[frame]["offset"] for cell in by_cell]
        spread.append(max(times) - min(times))
    return {"frames": len(common), **{k: percentiles(v) for k, v in figures.items()}, "ts_spread": percentiles(spread)}


def lock_figures(client: httpx.Client, session_id: str) -> dict[str, Any]:
    return client.get(f"/api/sessions/{session_id}/stats").json()["frame_lock"]


def received_fps(viewer: ScriptedViewer, start: float, end: float) -> float:
    """Interactive frames ``viewer`` received per second between ``start`` and ``end`` (perf_counter s)."""
    with viewer.lock:
        return sum(start <= f["at"] <= end and not f["still"] for f in viewer.frames) / (end - start)


def wall_phase(args: argparse.Namespace, client: httpx.Client, ws_url: str, service_pid: int,
               browser: Any) -> dict[str, Any]:
    wall = {"cols": args.cols, "rows": args.rows, "cell": list(args.cell), "bezel": list(args.bezel)}
    created = client.post("/api/sessions", json={"scene": args.scene, "wall": wall})
    created.raise_for_status()
    body = created.json()
    session_id = body["id"]
    wait_session_ready(client, session_id)
    cells = [f"{col},{row}" for row in range(args.rows) for col in range(args.cols)]
    with contextlib.ExitStack() as stack:
        pages: list[Any] = []
        if browser is not None:
            pages = stack.enter_context(pages_at(browser, [f"{body['viewer_url']}&cell={cell}" for cell in cells],
                                                    args.cell))
            scripted: list[ScriptedCell] = []
        else:
            scripted = [ScriptedCell(stack.enter_context(ws_client.connect(
                f"{ws_url}/ws/view?session={session_id}&cell={cell}", max_size=256 << 20))) for cell in cells]
        driver = ScriptedViewer(stack.enter_context(ws_client.connect(
            f"{ws_url}/ws/view?session={session_id}", max_size=256 << 20)))
        deadline = time.monotonic() + 120.0
        while (first := lock_figures(client, session_id))["cells"] < len(cells) or first["presents"] < 1:
            if time.monotonic() > deadline:
                raise RuntimeError("the wall's cells did not present a first frame within 120 s")
            time.sleep(0.2)
        started = time.perf_counter()
        stop = threading.Event()
        mover = threading.Thread(target=move, args=([driver], started + args.moving_s, args.input_hz, args.turn_s,
                                                    stop))
        mover.start()
        time.sleep(1.0)
        before, window_start, cpu = lock_figures(client, session_id), time.perf_counter(), CpuUse(service_pid)
        mover.join()
        after, window_end, cores = lock_figures(client, session_id), time.perf_counter(), cpu.cores()
        driver_fps = received_fps(driver, window_start, window_end)
        logs = [page.evaluate("() => window.tesseraWall ? window.tesseraWall.presents() : []") for page in pages]
        if args.present_log is not None and logs:
            args.present_log.write_text(json.dumps(logs))
        driver.stop()
        for cell in scripted:
            cell.stop()
    client.delete(f"/api/sessions/{session_id}")
    presented_fps = (after["presents"] - before["presents"]) / (window_end - window_start)
    timing = present_timing(logs, set(range(before["presented"] + 1, after["presented"] + 1))) if logs else None
    return {"size": body["size"], "presented_fps": presented_fps, "driver_fps": driver_fps, "cores": cores,
            **{key: after[key] for key in ("skew_p50_ms", "skew_p99_ms", "skew_samples", "lead_ms")},
            "present_timing": timing}


def single_phase(args: argparse.Namespace, client: httpx.Client, ws_url: str, size: list[int], service_pid: int,
                 browser: Any) -> dict[str, Any]:
    """One session of ``size`` turned by a scripted viewer (and shown by a Chromium page watching
    it, when ``browser``: the same pixels decoded and drawn in a browser as the wall's cells)."""
    created = client.post("/api/sessions", json={"scene": args.scene, "size": size})
    created.raise_for_status()
    body = created.json()
    wait_session_ready(client, body["id"])
    with contextlib.ExitStack() as stack:
        if browser is not None:
            stack.enter_context(pages_at(browser, [body["watch_url"]], (size[0], size[1])))
        viewer = ScriptedViewer(stack.enter_context(ws_client.connect(f"{ws_url}/ws/view?session={body['id']}",
                                                                      max_size=256 << 20)))
        started = time.perf_counter()
        mover = threading.Thread(target=move, args=([viewer], started + args.moving_s, args.input_hz, args.turn_s,
                                                    threading.Event()))
        mover.start()
        time.sleep(1.0)
        window_start, cpu = time.perf_counter(), CpuUse(service_pid)
        mover.join()
        fps, cores = received_fps(viewer, window_start, time.perf_counter()), cpu.cores()
        viewer.stop()
    client.delete(f"/api/sessions/{body['id']}")
    return {"size": size, "fps": fps, "cores": cores}


def measure(args: argparse.Namespace) -> dict[str, Any]:
    """``--rounds`` rounds of the wall and the single session, in turns (the wall first in odd rounds, the
    single session in even ones), so load that comes and goes on the machine falls on both."""
    (w, h), (bx, by) = args.cell, args.bezel
    size = [args.cols * w + (args.cols - 1) * bx, args.rows * h + (args.rows - 1) * by]
    server_args = ["--local-nodes", str(args.nodes), "--scene", args.scene, "--size", "64x48", "--stream", "tiles",
                   "--max-size", f"{size[0]}x{size[1]}", *shlex.split(args.server_args)]   # fits the single session
    coordinator, url = start_coordinator(server_args, log_level="warning")
    ws_url = url.replace("http://", "ws://")
    result: dict[str, Any] = {"cols": args.cols, "rows": args.rows, "cell": list(args.cell), "bezel": list(args.bezel),
                              "nodes": args.nodes, "scene": args.scene, "input_hz": args.input_hz,
                              "cells_are": "chromium" if args.chromium else "scripted", "server_args": args.server_args,
                              "rounds": []}
    try:
        with httpx.Client(base_url=url, timeout=120) as client, contextlib.ExitStack() as stack:
            browser = stack.enter_context(chromium()) if args.chromium else None
            wait_ready(client, args.nodes)
            for index in range(args.rounds):
                phases = {}
                for phase in (("wall", "single") if index % 2 == 0 else ("single", "wall")):
                    phases[phase] = (wall_phase(args, client, ws_url, coordinator.pid, browser) if phase == "wall" else
                                     single_phase(args, client, ws_url, size, coordinator.pid, browser))
                single_fps = phases["single"]["fps"]
                phases["fps_ratio"] = phases["wall"]["presented_fps"] / single_fps if single_fps else math.nan
                result["rounds"].append(phases)
    finally:
        coordinator.stop(timeout=30.0)
    rounds = result["rounds"]
    for r in rounds:
        r["cpu_ms_per_frame"] = {name: per_frame(r[name]["cores"], fps) for name, fps in
                                 (("wall", r["wall"]["driver_fps"]), ("single", r["single"]["fps"]))}
    result["fps_ratio"] = float(np.median([r["fps_ratio"] for r in rounds]))
    result["nodes_cpu_ratio"] = float(np.median([r["cpu_ms_per_frame"]["wall"]["nodes"] /
                                                 r["cpu_ms_per_frame"]["single"]["nodes"] for r in rounds]))
    result["coordinator_extra_ms"] = float(np.median([r["cpu_ms_per_frame"]["wall"]["coordinator"] -
                                                      r["cpu_ms_per_frame"]["single"]["coordinator"] for r in rounds]))
    result["wall_fps"] = float(np.median([r["wall"]["presented_fps"] for r in rounds]))
    result["single_fps"] = float(np.median([r["single"]["fps"] for r in rounds]))
    return result


def per_frame(cores: dict[str, float], fps: float) -> dict[str, float]:
    """CPU ms per frame made of the coordinator and of its nodes, from a window's cores busy at ``fps``."""
    return {key: 1000.0 * cores[key] / fps if fps else math.nan for key in ("coordinator", "nodes")}


def report(result: dict[str, Any]) -> str:
    first = result["rounds"][0]["wall"]
    lines = [
        f"{result['cols']}x{result['rows']} wall of {result['cell'][0]}x{result['cell'][1]} cells (bezel "
        f"{result['bezel'][0]}x{result['bezel'][1]}), {first['size'][0]}x{first['size'][1]} in all, "
        f"{result['nodes']} local nodes, {result['cells_are']} cells, driver at {result['input_hz']:g} Hz",
    ]
    for number, phases in enumerate(result["rounds"], start=1):
        wall, single = phases["wall"], phases["single"]
        skew = ("no skew measured" if wall["skew_p50_ms"] is None else
                f"skew p50 {wall['skew_p50_ms']:.2f} ms, p99 {wall['skew_p99_ms']:.2f} ms ({wall['skew_samples']} "
                f"frames), lead {wall['lead_ms']:.0f} ms")
        cores = " | ".join(f"{name} {' '.join(f'{k} {v:.2f}' for k, v in phase['cores'].items())}"
                           for name, phase in (("wall", wall), ("single", single)))
        cpu = " | ".join(f"{name} coordinator {ms['coordinator']:.0f}, nodes {ms['nodes']:.0f}"
                         for name, ms in phases["cpu_ms_per_frame"].items())
        lines += [f"round {number}: wall {wall['presented_fps']:5.1f} presented/s (driver {wall['driver_fps']:.1f}/s), "
                  f"single {single['fps']:5.1f}/s, ratio {phases['fps_ratio']:.3f}; {skew}",
                  f"  cores busy: {cores}", f"  CPU ms per frame made: {cpu}"]
        timing = wall.get("present_timing")
        if timing:
            lines.append(f"  the pages' presents ({timing['frames']} frames every cell presented; p50/p99/max ms): " +
                         "; ".join(f"{name} {f['p50']}/{f['p99']}/{f['max']}"
                                   for name, f in timing.items() if isinstance(f, dict)))
    lines.append(f"median over {len(result['rounds'])} rounds: wall {result['wall_fps']:.1f} presented/s, single "
                 f"{result['single_fps']:.1f}/s, wall / single throughput {result['fps_ratio']:.3f}; CPU per frame, "
                 f"wall / single: nodes {result['nodes_cpu_ratio']:.3f}, coordinator "
                 f"{result['coordinator_extra_ms']:+.1f} ms")
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m bench.wall", description=__doc__.split("\n\n")[0])
    parser.add_argument("--cols", type=int, default=2)
    parser.add_argument("--rows", type=int, default=2)
    parser.add_argument("--cell", type=size_parser(16, 8192), default=(640, 360))
    parser.add_argument("--bezel", type=size_parser(0, 1024), default=(0, 0), help="mullion between cells, BXxBY px")
    parser.add_argument("--nodes", type=int, default=3)
    parser.add_argument("--scene", default="builtin:cluster")
    parser.add_argument("--input-hz", type=float, default=30.0)
    parser.add_argument("--moving-s", type=float, default=8.0)
    parser.add_argument("--turn-s", type=float, default=8.0)
    parser.add_argument("--chromium", action="store_true",
                        help="cells are headless Chromium pages of the viewer (and a page watches the single session)")
    parser.add_argument("--rounds", type=int, default=1, help="rounds of wall and single session, in turns")
    parser.add_argument("--server-args", default="", help="more flags for python -m server")
    parser.add_argument("--present-log", type=Path, help="with --chromium: write the pages' present logs here (JSON)")
    parser.add_argument("--json", type=Path)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.cols < 1 or args.rows < 1 or args.nodes < 1 or args.rounds < 1 or args.moving_s <= 2.0:
        raise SystemExit("--cols, --rows, --nodes and --rounds must be >= 1, --moving-s > 2")
    result = measure(args)
    show_result(report(result), result, args.json, argv)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
