"""Input → frame latency of the notebook view (issue 33) through the kernel's comm, through the page's
own socket (``transport="direct"``) and on the plain viewer page, in one run on one coordinator.

``python -m bench.notebook [--nodes 2] [--scene builtin:cluster] [--size 640x360] [--rounds 3]
[--drag-s 4] [--json OUT]``

A real ``jupyter lab`` shows two views of two sessions of the scene (one per transport) and headless
Chromium drags the mouse across each in turn, and across the viewer page of the coordinator's
default session (the same scene and size): a drag orbits the camera with pointer moves at 60 Hz.
Each page measures its own input → frame latency with the viewer's tracker (web/latency.js: from
a camera input sent to the first frame drawn that answers it), p50 and p90 over the newest 60
answers, and the mean interval between answering frames. The three take turns, the order rotating
every round, each drag once the one before shows its still; the table gives each one's median
over the rounds, and the comm's and the direct socket's p50 over the page's. The comm's own cost
is measured apart, on this machine's clock: a frame's time from the kernel's relay to the page,
and an input's from the page to the kernel.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import statistics
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from bench.jupyter import VIEW_STATE_JS, free_port, jupyter_lab, run_first_cells, write_notebook
from bench.processes import show_result, start_coordinator
from bench.wall import chromium
from tessera.cli_values import size_parser

TRANSPORTS = ("page", "comm", "direct")
#: The viewer page's own latency summary.
PAGE_LATENCY_JS = "() => window.tessera && window.tessera.framesDrawn ? window.tessera.inputLatency : null"
#: Whether the viewer page shows its still (its session rests).
PAGE_STILL_JS = "() => Boolean(window.tessera && window.tessera.still)"
#: Pointer moves per second while dragging.
MOVE_HZ = 60.0
#: How long a view may take to show its still after a drag, ms.
REST_TIMEOUT_MS = 120_000


def view_latency_js(index: int) -> str:
    """The latency summary of the notebook's ``index``-th view."""
    return f"""() => {{
  const box = document.querySelectorAll(".tessera-view")[{index}];
  const state = box && box.parentElement.tesseraView;
  return state && state.framesDrawn ? state.inputLatency : null;
}}"""


def view_still_js(index: int) -> str:
    """Whether the notebook's ``index``-th view shows its still."""
    return f"""() => {{
  const box = document.querySelectorAll(".tessera-view")[{index}];
  const state = box && box.parentElement.tesseraView;
  return Boolean(state && state.still);
}}"""


def drag(page: Any, canvas: Any, seconds: float) -> None:
    """Orbit with the mouse on ``canvas`` for ``seconds``: to and fro across its middle."""
    page.bring_to_front()   # a page in the background gets no animation frames: it would send no input
    canvas.scroll_into_view_if_needed()
    box = canvas.bounding_box()
    x, y = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    reach = box["width"] / 4
    page.mouse.move(x, y)
    page.mouse.down()
    start = time.monotonic()
    step = 0
    while time.monotonic() - start < seconds:
        phase = (step % 120) / 120.0
        offset = reach * (4 * phase - 1 if phase < 0.5 else 3 - 4 * phase)
        page.mouse.move(x + offset, y)
        step += 1
        time.sleep(max(0.0, start + step / MOVE_HZ - time.monotonic()))
    page.mouse.up()


def measure(args: argparse.Namespace) -> dict[str, Any]:
    width, height = args.size
    lab_port = free_port()
    coordinator, url = start_coordinator(
        ["--local-nodes", str(args.nodes), "--scene", args.scene, "--size", f"{width}x{height}",
         "--allowed-origins", f"http://127.0.0.1:{lab_port}"], timeout=120.0)
    rounds: dict[str, list[dict[str, float]]] = {name: [] for name in TRANSPORTS}
    hops: list[dict[str, float]] = []
    try:
        with tempfile.TemporaryDirectory(prefix="tessera-bench-notebook-") as folder, contextlib.ExitStack() as stack:
            root = Path(folder)
            write_notebook(root / "views.ipynb", [
                "from IPython.display import display\nfrom tessera.client import Tessera\n"
                f"tessera = Tessera({url!r})\n"
                f"comm = tessera.open_session({args.scene!r}, size=({width}, {height})).show({width}, {height})\n"
                f"direct = tessera.open_session({args.scene!r}, size=({width}, {height})).show({width}, {height}, "
                "transport='direct')\n"
                "display(comm, direct)"])
            lab = stack.enter_context(jupyter_lab(root, 120.0, lab_port))
            browser = stack.enter_context(chromium())
            notebook = browser.new_page(viewport={"width": 1400, "height": 1300})
            notebook.on("console", lambda message: print("console:", message.text[:300], flush=True)
                        if message.type in ("warning", "error") else None)
            notebook.goto(lab.open_url("views.ipynb"))
            run_first_cells(notebook, 1, 120_000)
            viewer = browser.new_page(viewport={"width": width + 360, "height": height + 200})
            viewer.goto(f"{url}/")
            targets = {"page": (viewer, viewer.locator("#frame"), PAGE_LATENCY_JS, PAGE_STILL_JS),
                       "comm": (notebook, notebook.locator(".tessera-frame").nth(0), view_latency_js(0),
                                view_still_js(0)),
                       "direct": (notebook, notebook.locator(".tessera-frame").nth(1), view_latency_js(1),
                                  view_still_js(1))}
            for name, (page, canvas, latency_js, still_js) in targets.items():
                print(f"warming up {name}", flush=True)
                canvas.wait_for(timeout=120_000)
                drag(page, canvas, 1.0)   # warm up: the first answers are the slowest
                page.wait_for_function(f"() => ({latency_js})() !== null", timeout=120_000)
                page.wait_for_function(still_js, timeout=REST_TIMEOUT_MS)
            for index in range(args.rounds):
                order = TRANSPORTS[index % 3:] + TRANSPORTS[:index % 3]
                for name in order:
                    page, canvas, latency_js, still_js = targets[name]
                    drag(page, canvas, args.drag_s)
                    # The next drag starts once this session's still is shown: its samples would
                    # otherwise share the nodes with the next one's frames.
                    page.wait_for_function(still_js, timeout=REST_TIMEOUT_MS)
                    rounds[name].append(page.evaluate(latency_js))
                    if name == "comm":
                        view = notebook.evaluate(VIEW_STATE_JS)
                        hops.append({"frame_ms": view["frameHopMs"], "input_ms": view["inputHopMs"],
                                     "relay_wait_ms": view["relayWaitMs"]})
            sizes = {"comm": notebook.evaluate(VIEW_STATE_JS)["size"], "page": viewer.evaluate("window.tessera.size")}
    finally:
        coordinator.stop()
    figures = {name: {key: statistics.median(r[key] for r in rounds[name])
                      for key in ("p50_ms", "p90_ms", "interval_ms", "samples")} for name in TRANSPORTS}
    comm_hops = {key: statistics.median(h[key] for h in hops if h[key] is not None)
                 for key in ("frame_ms", "input_ms", "relay_wait_ms")}
    return {"benchmark": "notebook", "scene": args.scene, "size": [width, height], "nodes": args.nodes,
            "rounds": args.rounds, "drag_s": args.drag_s, "frame_sizes": sizes, "transports": figures,
            "per_round": rounds, "comm_hops": comm_hops,
            "comm_over_page_p50": figures["comm"]["p50_ms"] / figures["page"]["p50_ms"],
            "direct_over_page_p50": figures["direct"]["p50_ms"] / figures["page"]["p50_ms"],
            "load_average": os.getloadavg()}


def report(result: dict[str, Any]) -> str:
    lines = [f"input -> frame, {result['scene']} at {result['size'][0]}x{result['size'][1]}, {result['nodes']} local "
             f"nodes, median of {result['rounds']} rounds of {result['drag_s']:g} s drags",
             f"{'transport':<10}{'p50 ms':>9}{'p90 ms':>9}{'interval ms':>13}{'samples':>9}"]
    for name, row in result["transports"].items():
        lines.append(f"{name:<10}{row['p50_ms']:>9.1f}{row['p90_ms']:>9.1f}{row['interval_ms']:>13.1f}"
                     f"{row['samples']:>9.0f}")
    hops = result["comm_hops"]
    lines.append(f"the comm's own hops (median): kernel -> page {hops['frame_ms']:.1f} ms a frame, "
                 f"page -> kernel {hops['input_ms']:.1f} ms an input; a frame waited {hops['relay_wait_ms']:.1f} ms "
                 "in the relay for the page's acknowledgements")
    lines.append(f"comm / page p50: {result['comm_over_page_p50']:.2f} (goal <= 1.25); "
                 f"direct / page p50: {result['direct_over_page_p50']:.2f}")
    lines.append("load average (1, 5, 15 min) at the end: " + ", ".join(f"{v:.2f}" for v in result["load_average"]))
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m bench.notebook", description=__doc__.splitlines()[0])
    parser.add_argument("--nodes", type=int, default=2, help="local render nodes (default 2)")
    parser.add_argument("--scene", default="builtin:cluster", help="the scene (default builtin:cluster)")
    parser.add_argument("--size", type=size_parser(16, 4096), default=(640, 360), help="frame size WxH (640x360)")
    parser.add_argument("--rounds", type=int, default=3, help="turns of the three (default 3)")
    parser.add_argument("--drag-s", type=float, default=4.0, help="seconds of each drag (default 4)")
    parser.add_argument("--json", type=Path, help="write the result as JSON here")
    return parser


def main(argv: Sequence[str] | None = None) -> None:
    args = build_parser().parse_args(argv)
    result = measure(args)
    show_result(report(result), result, args.json, argv)


if __name__ == "__main__":
    main()
