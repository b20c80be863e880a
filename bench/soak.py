"""``python -m bench.soak --minutes M``: a long run on loopback, watched for leaks and lost frames.

A coordinator (no ``--local-nodes``) and ``--nodes`` render nodes, each a process of its own so that
one can be restarted: every ``--restart-every-s`` the next node in turn gets SIGTERM and is started
again. Meanwhile

* one persistent viewer turns the camera over its socket at ``--camera-hz`` and records when each
  frame arrives (it reconnects, and counts it, should the coordinator drop it);
* every second another viewer connects, reads its hello and one frame, and leaves;
* every ``--sample-every-s`` the coordinator's and each node's RSS (``/proc/PID/status`` VmRSS),
  threads and open file descriptors (``/proc/PID/fd``) are sampled, with no churn viewer open, and
  with them the CPU seconds of those processes and of the whole machine (``/proc/stat``): on a shared
  machine the report says how many cores other processes took, on average and at each gap over 1 s.

It reports, per process kind, the first sample after the warm-up and the last one (both taken with
every node up and no restart under way) and their growth; the longest gap between frames on the
persistent viewer outside restart windows (a window: from SIGTERM until the new node is ready in
``/api/stats``, plus 1 s) and inside them; frames, viewer connections, restarts, crashes, tracebacks
in the logs; and whether each goal is met: growth ≤ 10 %, no gap over 1 s outside restart windows,
no crash. Every process's output goes to a file in ``--log-dir``.

Bounded: the run ends after ``--minutes``, every wait has a deadline, and every process it started
is stopped on the way out, on errors and Ctrl-C (SIGINT or SIGTERM) included.
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import json
import math
import os
import signal
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import httpx
import websockets.sync.client as ws_client

from bench.processes import CLOCK_TICKS, PYTHON, LoggedProcess, orbit, show_result, start_coordinator
from server.local_nodes import llvmpipe_threads_per_node
from tessera.cli_values import size_parser
from tessera.wire.protocol import unpack_frame

GROWTH_GOAL_PCT = 10.0
GAP_GOAL_S = 1.0
WINDOW_TAIL_S = 1.0  # a restart window lasts until the new node is ready, plus this
STARTUP_TIMEOUT_S = 180.0
REJOIN_TIMEOUT_S = 120.0
STOP_TIMEOUT_S = 20.0
CHURN_READ_TIMEOUT_S = 10.0
#: the soak's own HTTP requests close their connection, so that none is open in the coordinator's FD count
NO_KEEPALIVE = {"Connection": "close"}


def proc_figures(pid: int) -> dict[str, Any] | None:
    """RSS (kB), threads, open file descriptors and CPU seconds so far (user + system) of ``pid``
    from /proc; None once it is gone."""
    try:
        with open(f"/proc/{pid}/status") as status:
            fields = dict(line.split(":", 1) for line in status if ":" in line)
        with open(f"/proc/{pid}/stat") as stat:
            times = stat.read().rsplit(")", 1)[1].split()[11:13]
        return {"rss_kb": int(fields["VmRSS"].split()[0]), "threads": int(fields["Threads"]),
                "fds": len(os.listdir(f"/proc/{pid}/fd")), "cpu_s": (int(times[0]) + int(times[1])) / CLOCK_TICKS}
    except (OSError, KeyError, ValueError, IndexError):
        return None


def machine_busy_s() -> float:
    """CPU seconds the whole machine spent busy so far, summed over its cores (/proc/stat: all
    but idle and iowait)."""
    with open("/proc/stat") as stat:
        ticks = [int(v) for v in stat.readline().split()[1:]]
    return (sum(ticks[:8]) - ticks[3] - ticks[4]) / CLOCK_TICKS


class PersistentViewer:
    """One viewer for the whole run, on a thread: turns the camera about its target at ``hz`` over its
    own socket and records every frame's arrival (monotonic time, frame id). If the coordinator drops
    it, it connects again (counted) — the browser viewer does the same."""

    def __init__(self, ws_url: str, hz: float, turn_s: float) -> None:
        self.ws_url, self.hz, self.turn_s = ws_url, hz, turn_s
        self.arrivals: list[tuple[float, int]] = []
        self.backwards = 0
        self.drops: list[tuple[float, str]] = []
        self.cameras_sent = 0
        self._stop = threading.Event()
        self._first = threading.Event()
        self._thread = threading.Thread(target=self._run, name="persistent-viewer", daemon=True)

    def start(self, timeout: float) -> None:
        self._thread.start()
        if not self._first.wait(timeout):
            self.stop()
            raise RuntimeError(f"the persistent viewer got no frame within {timeout:.0f} s: {self.drops}")

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=10)

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self._session()
            except Exception as exc:  # a drop is a finding: record it, connect again
                self.drops.append((time.monotonic(), f"{type(exc).__name__}: {exc}"))
                self._stop.wait(0.5)

    def _session(self) -> None:
        with ws_client.connect(self.ws_url, max_size=256 << 20, open_timeout=10) as ws:
            hello = json.loads(ws.recv(timeout=10))
            camera, started = hello["camera"], time.monotonic()
            next_send = started
            while not self._stop.is_set():
                now = time.monotonic()
                if camera is not None and now >= next_send:
                    ws.send(json.dumps({"type": "camera",
                                        "camera": orbit(camera, 2.0 * math.pi * (now - started) / self.turn_s)}))
                    self.cameras_sent += 1
                    next_send = max(next_send + 1.0 / self.hz, now)
                try:
                    message = ws.recv(timeout=max(0.001, next_send - time.monotonic()))
                except TimeoutError:
                    continue
                if isinstance(message, bytes):
                    frame_id = unpack_frame(message).frame_id
                    if self.arrivals and frame_id <= self.arrivals[-1][1]:
                        self.backwards += 1
                    self.arrivals.append((time.monotonic(), frame_id))
                    self._first.set()
                elif camera is None and (text := json.loads(message)).get("type") == "scene":
                    camera = text["camera"]


class ChurnViewers:
    """Every ``interval`` s a viewer connects, reads its hello and one frame, and leaves; holds
    ``quiet`` while one is open, so that samples never count a churn viewer's socket."""

    def __init__(self, ws_url: str, interval: float, quiet: threading.Lock) -> None:
        self.ws_url, self.interval, self.quiet = ws_url, interval, quiet
        self.completed = 0
        self.failures: list[tuple[float, str]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="churn-viewers", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=CHURN_READ_TIMEOUT_S * 3)

    def _run(self) -> None:
        next_at = time.monotonic()
        while not self._stop.wait(max(0.0, next_at - time.monotonic())):
            next_at += self.interval
            with self.quiet:
                try:
                    self._visit()
                    self.completed += 1
                except Exception as exc:
                    self.failures.append((time.monotonic(), f"{type(exc).__name__}: {exc}"))

    def _visit(self) -> None:
        with ws_client.connect(self.ws_url, max_size=256 << 20, open_timeout=CHURN_READ_TIMEOUT_S) as ws:
            deadline = time.monotonic() + CHURN_READ_TIMEOUT_S
            hello = json.loads(ws.recv(timeout=CHURN_READ_TIMEOUT_S))
            if hello.get("type") != "hello":
                raise RuntimeError(f"first message is not a hello: {hello}")
            while not isinstance(ws.recv(timeout=max(0.001, deadline - time.monotonic())), bytes):
                pass


@dataclass
class Restart:
    """One node restart (monotonic times): SIGTERM sent, old process gone, new one ready (None: never)."""

    slot: int
    old_name: str
    new_name: str
    requested: float
    stopped: float = math.nan
    old_returncode: int | None = None
    old_killed: bool = False
    ready: float | None = None


@dataclass
class Soak:
    """The processes of one run and what was recorded about them."""

    args: argparse.Namespace
    log_dir: Path
    coordinator: LoggedProcess | None = None
    url: str = ""
    nodes: list[LoggedProcess] = field(default_factory=list)
    generations: list[int] = field(default_factory=list)
    retired: list[LoggedProcess] = field(default_factory=list)
    restarts: list[Restart] = field(default_factory=list)
    crashes: list[dict[str, Any]] = field(default_factory=list)
    samples: list[dict[str, Any]] = field(default_factory=list)
    exits: dict[str, dict[str, Any]] = field(default_factory=dict)
    restarting: bool = False
    lock: threading.Lock = field(default_factory=threading.Lock)
    quiet: threading.Lock = field(default_factory=threading.Lock)

    @property
    def ws_base(self) -> str:
        return self.url.replace("http://", "ws://", 1)

    def start_coordinator(self) -> None:
        width, height = self.args.size
        self.coordinator, self.url = start_coordinator(
            ["--host", "127.0.0.1", "--scene", self.args.scene, "--size", f"{width}x{height}",
             *self.args.server_args.split()], log_path=self.log_dir / "coordinator.log", stop_timeout=STOP_TIMEOUT_S)

    @contextlib.contextmanager
    def cluster(self, launched: float) -> Iterator[tuple[httpx.Client, PersistentViewer]]:
        """Start the coordinator and ``--nodes`` nodes, wait (from ``launched``) until every node is
        ready and calibrated, and open the persistent viewer: a client of the API and that viewer."""
        self.start_coordinator()
        for slot in range(self.args.nodes):
            self.start_node(slot)
        with httpx.Client(base_url=self.url, headers=NO_KEEPALIVE) as client:
            names = {node.label for node in self.nodes}
            if not self.wait_ready(client, names, launched + STARTUP_TIMEOUT_S, calibrated=True):
                raise RuntimeError(f"{self.args.nodes} nodes not ready and calibrated within "
                                   f"{STARTUP_TIMEOUT_S:.0f} s; see the logs in {self.log_dir}")
            viewer = PersistentViewer(self.ws_base + "/ws/view", self.args.camera_hz, self.args.turn_s)
            viewer.start(timeout=60)
            yield client, viewer

    def start_node(self, slot: int) -> LoggedProcess:
        if slot == len(self.generations):
            self.generations.append(0)
        self.generations[slot] += 1
        generation = self.generations[slot]
        name = f"soak{slot + 1}-g{generation}"
        threads = str(llvmpipe_threads_per_node(self.args.nodes))
        child = LoggedProcess([PYTHON, "-m", "node", "--coordinator", self.ws_base + "/ws/node", "--name", name],
                              label=name, env={"LP_NUM_THREADS": os.environ.get("LP_NUM_THREADS", threads)},
                              log_path=self.log_dir / f"node-{name}.log", stop_timeout=STOP_TIMEOUT_S)
        with self.lock:
            if slot < len(self.nodes):
                self.retired.append(self.nodes[slot])
                self.nodes[slot] = child
            else:
                self.nodes.append(child)
        return child

    def stats(self, client: httpx.Client) -> dict[str, Any]:
        return client.get("/api/stats", timeout=10).raise_for_status().json()

    def wait_ready(self, client: httpx.Client, names: set[str], deadline: float, calibrated: bool) -> bool:
        """Poll /api/stats until every node in ``names`` is ready (and calibrated); False at ``deadline``."""
        while time.monotonic() < deadline:
            with contextlib.suppress(httpx.HTTPError):
                nodes = {n["name"]: n for n in self.stats(client)["nodes"]}
                if all(name in nodes and nodes[name]["state"] == "ready"
                       and (not calibrated or nodes[name]["calibration_ms"] is not None) for name in names):
                    return True
            if self.coordinator is not None and self.coordinator.process.poll() is not None:
                return False
            time.sleep(0.1)
        return False

    def restart(self, client: httpx.Client, slot: int, deadline: float) -> Restart:
        old = self.nodes[slot]
        record = Restart(slot, old.label, "", time.monotonic())
        with self.lock:
            self.restarting = True
            self.restarts.append(record)
        try:
            record.old_returncode, record.old_killed = old.stop(signal.SIGTERM), old.killed
            record.stopped = time.monotonic()
            self.exits[old.label] = {"returncode": record.old_returncode, "killed": record.old_killed,
                                     "signal": "SIGTERM", "tracebacks": old.tracebacks}
            new = self.start_node(slot)
            record.new_name = new.label
            if self.wait_ready(client, {new.label}, min(deadline, time.monotonic() + REJOIN_TIMEOUT_S), False):
                record.ready = time.monotonic()
        finally:
            with self.lock:
                self.restarting = False
        return record

    def check_alive(self, now: float) -> bool:
        """Record processes that exited unasked; a dead node is started again. False: the coordinator died."""
        assert self.coordinator is not None
        if self.coordinator.process.poll() is not None:
            self.crashes.append({"process": "coordinator", "at": now, "returncode": self.coordinator.process.returncode,
                                 "last_lines": list(self.coordinator.lines)[-30:]})
            return False
        for slot, node in enumerate(list(self.nodes)):
            if node.process.poll() is not None:
                self.crashes.append({"process": node.label, "at": now, "returncode": node.process.returncode,
                                     "last_lines": list(node.lines)[-30:]})
                self.exits[node.label] = {"returncode": node.stop(), "killed": node.killed, "signal": None,
                                          "tracebacks": node.tracebacks}
                self.start_node(slot)
        return True

    def sample(self, client: httpx.Client, t0: float) -> None:
        with self.quiet, self.lock:
            nodes = {node.label: proc_figures(node.pid) for node in self.nodes}
            restarting = self.restarting
            coordinator = proc_figures(self.coordinator.pid) if self.coordinator else None
        sample: dict[str, Any] = {"t": round(time.monotonic() - t0, 2), "restarting": restarting,
                                  "coordinator": coordinator, "nodes": nodes, "soak": proc_figures(os.getpid()),
                                  "machine_busy_s": machine_busy_s(), "loadavg_1m": os.getloadavg()[0]}
        with contextlib.suppress(httpx.HTTPError):
            stats = self.stats(client)
            sample.update(viewers=stats["viewers"], viewer_stats=len(stats["viewer_stats"]),
                          nodes_listed=len(stats["nodes"]), frame=stats["frame"])
        self.samples.append(sample)

    def stop_all(self) -> None:
        """Stop every process still running: nodes (SIGTERM) first, then the coordinator (SIGINT)."""
        for node in [*self.nodes, *self.retired]:
            if node.label not in self.exits:
                self.exits[node.label] = {"returncode": node.stop(signal.SIGTERM), "killed": node.killed,
                                          "signal": "SIGTERM", "tracebacks": node.tracebacks}
        if self.coordinator is not None and "coordinator" not in self.exits:
            self.exits["coordinator"] = {"returncode": self.coordinator.stop(signal.SIGINT),
                                         "killed": self.coordinator.killed, "signal": "SIGINT",
                                         "tracebacks": self.coordinator.tracebacks}


class Sampler:
    """Calls ``soak.sample`` every ``interval`` s on a thread of its own."""

    def __init__(self, soak: Soak, interval: float, t0: float) -> None:
        self.soak, self.interval, self.t0 = soak, interval, t0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="sampler", daemon=True)

    def _run(self) -> None:
        with httpx.Client(base_url=self.soak.url, headers=NO_KEEPALIVE) as client:
            next_at = time.monotonic()
            while not self._stop.wait(max(0.0, next_at - time.monotonic())):
                next_at += self.interval
                self.soak.sample(client, self.t0)

    @contextlib.contextmanager
    def running(self) -> Iterator[None]:
        self._thread.start()
        try:
            yield
        finally:
            self._stop.set()
            self._thread.join(timeout=30)


def drive(soak: Soak) -> dict[str, Any]:
    """Start everything, run for ``--minutes`` with restarts, stop the viewers; what was recorded."""
    args = soak.args
    run_s = args.minutes * 60.0
    launched = time.monotonic()
    hard_deadline = launched + STARTUP_TIMEOUT_S + run_s + REJOIN_TIMEOUT_S
    with soak.cluster(launched) as (client, viewer):
        churn = ChurnViewers(soak.ws_base + "/ws/view", args.churn_every_s, soak.quiet)
        t0 = time.monotonic()
        end, next_restart, slot = t0 + run_s, t0 + args.restart_every_s, 0
        coordinator_up = True
        churn.start()
        try:
            with Sampler(soak, args.sample_every_s, t0).running():
                while (now := time.monotonic()) < end and now < hard_deadline:
                    if not (coordinator_up := soak.check_alive(now)):
                        break
                    if args.restart_every_s > 0 and now >= next_restart:
                        soak.restart(client, slot, hard_deadline)
                        slot, next_restart = (slot + 1) % args.nodes, next_restart + args.restart_every_s
                    time.sleep(min(0.2, max(0.0, end - time.monotonic())))
                t_end = time.monotonic()
        finally:
            churn.stop()
            viewer.stop()
    return {"t0": t0, "t_end": t_end, "run_s": t_end - t0, "viewer": viewer, "churn": churn,
            "coordinator_up": coordinator_up}


def gap_figures(arrivals: list[tuple[float, int]], windows: list[tuple[float, float]], t0: float,
                t_end: float) -> dict[str, Any]:
    """Gaps between frame arrivals (the run's start and end count as arrivals), split by whether they
    touch a restart window; the longest of each kind (s), where it started (s after t0), and every
    gap over the goal outside the windows."""
    times = [t0, *(t for t, _ in arrivals if t0 <= t <= t_end), t_end]
    longest = {"outside": (0.0, math.nan), "inside": (0.0, math.nan)}
    over_goal = []
    for a, b in itertools.pairwise(times):
        kind = "inside" if any(a < w1 and b > w0 for w0, w1 in windows) else "outside"
        if b - a > longest[kind][0]:
            longest[kind] = (b - a, a - t0)
        if kind == "outside" and b - a > GAP_GOAL_S:
            over_goal.append({"at_s": round(a - t0, 2), "gap_s": round(b - a, 3)})
    return {"longest_gap_outside_s": longest["outside"][0], "longest_gap_outside_at_s": longest["outside"][1],
            "longest_gap_inside_s": longest["inside"][0], "longest_gap_inside_at_s": longest["inside"][1],
            "gaps_over_goal_outside": over_goal}


def growth(first: float, last: float) -> float:
    return 100.0 * (last - first) / first if first else math.nan


def memory_figures(samples: list[dict[str, Any]], nodes: int, warmup_s: float) -> dict[str, Any]:
    """Per kind (coordinator; nodes: the sum over the live nodes) the first steady sample at or after
    ``warmup_s`` and the last one, and growth %. Steady: no restart under way, every node sampled."""
    steady = [s for s in samples if not s["restarting"] and s["coordinator"] is not None
              and len(s["nodes"]) == nodes and all(v is not None for v in s["nodes"].values())]
    after = [s for s in steady if s["t"] >= warmup_s]
    if len(after) < 2:
        return {"steady_samples": len(after)}
    first, last = after[0], after[-1]

    def kind(sample: dict[str, Any], key: str) -> dict[str, int]:
        if key == "coordinator":
            return {m: sample["coordinator"][m] for m in ("rss_kb", "fds", "threads")}
        return {m: sum(v[m] for v in sample["nodes"].values()) for m in ("rss_kb", "fds", "threads")}

    out: dict[str, Any] = {"steady_samples": len(after), "first_t": first["t"], "last_t": last["t"]}
    for key in ("coordinator", "nodes"):
        a, b = kind(first, key), kind(last, key)
        out[key] = {"first": a, "last": b, **{f"{m}_growth_pct": growth(a[m], b[m]) for m in a},
                    "rss_kb_peak": max(kind(s, key)["rss_kb"] for s in after)}
    return out


def machine_figures(samples: list[dict[str, Any]], gaps_over_goal: list[dict[str, Any]]) -> dict[str, Any]:
    """What the machine did besides the soak, per sampling interval: its busy cores (/proc/stat), the
    cores the soak's own processes used (coordinator, nodes, this process; a node started or ended
    within the interval is left out, so a restart counts a little to the others), the others' cores
    (busy − own), the 1-minute load average and the coordinator's frames/s. Summed up, and for each
    gap over the goal outside restart windows, the interval it began in."""
    intervals = []
    for a, b in itertools.pairwise(samples):
        dt = b["t"] - a["t"]
        if dt <= 0 or "machine_busy_s" not in a:
            continue
        pairs = [(a["coordinator"], b["coordinator"]), (a["soak"], b["soak"]),
                 *((a["nodes"].get(name), figures) for name, figures in b["nodes"].items())]
        own = sum(y["cpu_s"] - x["cpu_s"] for x, y in pairs if x and y) / dt
        busy = (b["machine_busy_s"] - a["machine_busy_s"]) / dt
        intervals.append({"t": a["t"], "t_end": b["t"], "busy_cores": busy, "own_cores": own,
                          "others_cores": max(0.0, busy - own), "loadavg_1m": b["loadavg_1m"],
                          "fps": (b["frame"] - a["frame"]) / dt if "frame" in a and "frame" in b else None,
                          "restarting": a["restarting"] or b["restarting"]})
    if not intervals:
        return {"cores": os.cpu_count(), "intervals": []}
    others = [i["others_cores"] for i in intervals]
    fps = sorted(i["fps"] for i in intervals if i["fps"] is not None)
    for gap in gaps_over_goal:
        at = next((i for i in intervals if i["t"] <= gap["at_s"] < i["t_end"]), None)
        if at is not None:
            gap.update(others_cores=round(at["others_cores"], 2), busy_cores=round(at["busy_cores"], 2),
                       fps=None if at["fps"] is None else round(at["fps"], 1))
    return {"cores": os.cpu_count(), "busy_cores_mean": sum(i["busy_cores"] for i in intervals) / len(intervals),
            "own_cores_mean": sum(i["own_cores"] for i in intervals) / len(intervals),
            "others_cores_mean": sum(others) / len(others), "others_cores_max": max(others),
            "others_over_1_core_share": sum(o >= 1.0 for o in others) / len(others),
            "loadavg_1m_max": max(i["loadavg_1m"] for i in intervals),
            "fps_median": fps[len(fps) // 2] if fps else None, "intervals": intervals}


def node_instances(samples: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Each node process's first, peak and last sampled RSS (kB) and FDs."""
    seen: dict[str, list[tuple[float, dict[str, int]]]] = {}
    for sample in samples:
        for name, figures in sample["nodes"].items():
            if figures is not None:
                seen.setdefault(name, []).append((sample["t"], figures))
    return [{"name": name, "samples": len(series), "first_t": series[0][0], "last_t": series[-1][0],
             "rss_kb_first": series[0][1]["rss_kb"], "rss_kb_peak": max(f["rss_kb"] for _, f in series),
             "rss_kb_last": series[-1][1]["rss_kb"], "fds_first": series[0][1]["fds"],
             "fds_last": series[-1][1]["fds"]} for name, series in seen.items()]


def figures(soak: Soak, run: dict[str, Any]) -> dict[str, Any]:
    args, t0, t_end = soak.args, run["t0"], run["t_end"]
    viewer: PersistentViewer = run["viewer"]
    churn: ChurnViewers = run["churn"]
    windows = [(r.requested, (r.ready if r.ready is not None else t_end) + WINDOW_TAIL_S) for r in soak.restarts]
    warmup_s = args.warmup_s if args.warmup_s is not None else min(max(30.0, 0.1 * run["run_s"]), run["run_s"] / 2)
    gaps = gap_figures(viewer.arrivals, windows, t0, t_end)
    memory = memory_figures(soak.samples, args.nodes, warmup_s)
    restarts = [{**asdict(r), "requested_s": r.requested - t0, "stop_s": r.stopped - r.requested,
                 "ready_after_s": None if r.ready is None else r.ready - r.requested} for r in soak.restarts]
    for r in restarts:
        del r["requested"], r["stopped"], r["ready"]
    unclean = {label: e for label, e in soak.exits.items() if e["returncode"] != 0 or e["killed"]}
    tracebacks = {label: e["tracebacks"] for label, e in soak.exits.items() if e["tracebacks"]}
    frames = [a for a in viewer.arrivals if t0 <= a[0] <= t_end]
    result: dict[str, Any] = {
        "minutes": args.minutes, "nodes": args.nodes, "scene": args.scene, "size": list(args.size),
        "restart_every_s": args.restart_every_s, "sample_every_s": args.sample_every_s, "warmup_s": warmup_s,
        "camera_hz": args.camera_hz, "run_s": run["run_s"], "completed": run["coordinator_up"],
        "frames_received": len(frames), "fps": len(frames) / run["run_s"] if run["run_s"] > 0 else math.nan,
        "frames_backwards": viewer.backwards, "cameras_sent": viewer.cameras_sent,
        "viewer_drops": [{"at_s": t - t0, "why": why} for t, why in viewer.drops],
        **gaps,
        "viewer_connections": churn.completed,
        "viewer_failures": [{"at_s": t - t0, "why": why} for t, why in churn.failures],
        "restarts_done": len(soak.restarts), "restarts_rejoined": sum(r.ready is not None for r in soak.restarts),
        "restarts": restarts,
        "memory": memory, "node_instances": node_instances(soak.samples),
        "machine": machine_figures(soak.samples, gaps["gaps_over_goal_outside"]), "samples": soak.samples,
        "crashes": soak.crashes, "exits": soak.exits, "unclean_exits": unclean, "tracebacks": tracebacks,
        "coordinator_tracebacks": soak.coordinator.tracebacks if soak.coordinator else 0,
        "first_traceback": next((c.first_traceback for c in [soak.coordinator, *soak.retired, *soak.nodes]
                                 if c is not None and c.first_traceback), []),
        "log_dir": str(soak.log_dir),
    }
    growths = [memory.get(kind, {}).get(f"{m}_growth_pct", math.nan) for kind in ("coordinator", "nodes")
               for m in ("rss_kb", "fds")]
    result["goals"] = {
        "growth_le_10pct": bool(all(g <= GROWTH_GOAL_PCT for g in growths)),
        "no_gap_over_1s_outside_restarts": gaps["longest_gap_outside_s"] <= GAP_GOAL_S,
        "no_crash": not soak.crashes and not unclean and not tracebacks and run["coordinator_up"],
        "every_restart_rejoined": result["restarts_rejoined"] == result["restarts_done"],
    }
    return result


def report(result: dict[str, Any]) -> str:
    def mb(kb: float) -> str:
        return f"{kb / 1024:.1f} MB"

    size = result["size"]
    lines = [f"Tessera soak: {result['run_s'] / 60:.1f} min, {result['nodes']} nodes, {result['scene']} at "
             f"{size[0]}x{size[1]}, a node restarted every {result['restart_every_s']:g} s, samples every "
             f"{result['sample_every_s']:g} s (growth from the first steady sample after {result['warmup_s']:.0f} s)"]
    memory = result["memory"]
    lines.append(f"  {'kind':<14}{'RSS first → last':<28}{'growth':>9}   {'FDs first → last':<18}{'growth':>9}"
                 f"   {'threads':<10}")
    for kind, label in (("coordinator", "coordinator"), ("nodes", "nodes (sum)")):
        m = memory.get(kind)
        if m is None:
            lines.append(f"  {label:<14}too few steady samples ({memory['steady_samples']})")
            continue
        a, b = m["first"], m["last"]
        lines.append(f"  {label:<14}{mb(a['rss_kb']) + ' → ' + mb(b['rss_kb']):<28}{m['rss_kb_growth_pct']:>+8.1f}%"
                     f"   {str(a['fds']) + ' → ' + str(b['fds']):<18}{m['fds_growth_pct']:>+8.1f}%"
                     f"   {a['threads']} → {b['threads']}")
    lines.append("  over time (t s: coordinator RSS / FDs; nodes' RSS sum / FDs sum; viewers listed):")
    samples = result["samples"]
    shown = sorted({*range(0, len(samples), max(1, math.ceil(len(samples) / 12))), len(samples) - 1})
    for s in (samples[i] for i in shown if i >= 0):
        c = s["coordinator"] or {"rss_kb": 0, "fds": 0}
        live = [v for v in s["nodes"].values() if v is not None]
        lines.append(f"    {s['t']:7.1f}  {mb(c['rss_kb']):>9} / {c['fds']:3d}   "
                     f"{mb(sum(v['rss_kb'] for v in live)):>9} / {sum(v['fds'] for v in live):3d}   "
                     f"{s.get('viewers', '?')}{'  (restart under way)' if s['restarting'] else ''}")
    ready = [r["ready_after_s"] for r in result["restarts"] if r["ready_after_s"] is not None]
    lines += [
        f"  frames          {result['frames_received']} on the persistent viewer ({result['fps']:.1f} fps), "
        f"{result['frames_backwards']} out of order, {len(result['viewer_drops'])} drops of its socket",
        f"  longest gap     {result['longest_gap_outside_s']:.2f} s outside restart windows "
        f"(at {result['longest_gap_outside_at_s']:.0f} s), {result['longest_gap_inside_s']:.2f} s inside; "
        f"{len(result['gaps_over_goal_outside'])} gaps > {GAP_GOAL_S:g} s outside",
        *gap_lines(result),
        f"  viewers         {result['viewer_connections']} connected, read hello + a frame, left; "
        f"{len(result['viewer_failures'])} failed",
        f"  restarts        {result['restarts_done']} done, {result['restarts_rejoined']} rejoined"
        + (f", ready {min(ready):.1f}–{max(ready):.1f} s after SIGTERM" if ready else ""),
        f"  crashes         {len(result['crashes'])} unasked exits, {len(result['unclean_exits'])} unclean stops, "
        f"tracebacks {result['tracebacks'] or 'none'}",
        "  goals           " + ", ".join(f"{name} {'yes' if ok else 'NO'}" for name, ok in result["goals"].items()),
        f"  logs            {result['log_dir']}",
    ]
    return "\n".join(lines)


def gap_lines(result: dict[str, Any]) -> list[str]:
    """The machine besides the soak, and what it was doing at each gap over the goal."""
    machine = result.get("machine", {})
    if not machine.get("intervals"):
        return []
    m = machine
    lines = [f"  machine         {m['cores']} cores, busy {m['busy_cores_mean']:.2f} on average: the soak's "
             f"processes {m['own_cores_mean']:.2f}, others {m['others_cores_mean']:.2f} (≥ 1 core "
             f"{100 * m['others_over_1_core_share']:.0f} % of the time, at most {m['others_cores_max']:.2f}; "
             f"load average up to {m['loadavg_1m_max']:.1f}); coordinator {m['fps_median']:.1f} frames/s "
             "(median of the sample intervals)"]
    for gap in result["gaps_over_goal_outside"]:
        if "others_cores" in gap:
            lines.append(f"    gap {gap['gap_s']:.2f} s at {gap['at_s']:.0f} s: others {gap['others_cores']:.2f} "
                         f"cores, busy {gap['busy_cores']:.2f}, coordinator {gap['fps']} frames/s in that interval")
    return lines


def run_parser(prog: str, description: str, nodes: int) -> argparse.ArgumentParser:
    """A command line parser with the options every run on a :class:`Soak` reads (``--nodes``, whose
    default is ``nodes``, the scene and size, the persistent viewer's camera, extra server flags, where
    the logs and the figures go); each benchmark adds its own."""
    parser = argparse.ArgumentParser(prog=prog, description=description)
    parser.add_argument("--nodes", type=int, default=nodes)
    parser.add_argument("--scene", default="builtin:cluster")
    parser.add_argument("--size", type=size_parser(16, 8192), default=(640, 360))
    parser.add_argument("--camera-hz", type=float, default=30.0, help="camera messages per second (default 30)")
    parser.add_argument("--turn-s", type=float, default=20.0, help="seconds per turn of the camera (default 20)")
    parser.add_argument("--server-args", default="", help="extra flags for python -m server")
    parser.add_argument("--log-dir", type=Path, help="process logs go here (default: a new temporary folder)")
    parser.add_argument("--json", type=Path, help="write the figures here")
    return parser


def build_parser() -> argparse.ArgumentParser:
    parser = run_parser("python -m bench.soak", __doc__.split("\n\n")[0], nodes=4)
    parser.add_argument("--minutes", type=float, required=True, help="length of the run after start-up")
    parser.add_argument("--restart-every-s", type=float, default=60.0, help="0: no restarts (default 60)")
    parser.add_argument("--sample-every-s", type=float, default=5.0)
    parser.add_argument("--warmup-s", type=float,
                        help="growth counts from the first steady sample after this (default: 10 %% of the run, "
                             "at least 30 s, at most half the run)")
    parser.add_argument("--churn-every-s", type=float, default=1.0, help="a viewer comes and goes this often")
    return parser


def _interrupt(signum: int, _frame: Any) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


def run_bench(args: argparse.Namespace, prefix: str, drive: Callable[[Soak], dict[str, Any]],
              figures: Callable[[Soak, dict[str, Any]], dict[str, Any]],
              report: Callable[[dict[str, Any]], str], argv: list[str] | None) -> dict[str, Any]:
    """Run ``drive`` on a :class:`Soak` (logs in ``args.log_dir`` or a new temporary folder named
    ``prefix…``), stop every process on the way out (SIGTERM too), print ``report`` of the
    ``figures`` and write them to ``args.json`` if given; the figures."""
    log_dir = args.log_dir or Path(tempfile.mkdtemp(prefix=prefix))
    log_dir.mkdir(parents=True, exist_ok=True)
    soak = Soak(args, log_dir)
    in_main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, _interrupt) if in_main else None
    try:
        run = drive(soak)
    finally:
        soak.stop_all()
        if in_main:
            signal.signal(signal.SIGTERM, previous)
    result = figures(soak, run)
    show_result(report(result), result, args.json, argv)
    return result


def main(argv: list[str] | None = None) -> int:
    run_bench(build_parser().parse_args(argv), "tessera-soak-", drive, figures, report, argv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
