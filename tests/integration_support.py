"""Helpers for the real-process integration tests: reference renders, image comparison, polling."""

from __future__ import annotations

import contextlib
import io
import json
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
from PIL import Image

from bench.images import psnr
from bench.processes import orbit
from tests.conftest import PYTHON, REPO, seconds

#: Real scenes the integration tests render, by short name: paths under ../shared/scenes.
SCENE_FILES = {
    "bunny": "bunny/bun_zipper.ply",
    "dragon": "large_scan/stanford_dragon_vrip_res2_202k.ply",
    "engine": "gltf_small/2CylinderEngine.glb",
    "diorama": "multi_object/sd_macross_city_diorama.glb",
}


def render_once(scene: str, camera: dict[str, Any], size: tuple[int, int], workdir: Path,
                scene_time: float | None = None, objects: dict[str, Any] | None = None,
                msaa: int | None = None, still_samples: int | None = None, clip: dict[str, Any] | None = None,
                highlight: str | None = None, lod_error_px: float | None = None,
                point_budget: int | None = None) -> np.ndarray:
    """The single-node reference: ``python -m node --render-once`` (at ``scene_time``, with the
    ``objects`` poses, ``msaa`` samples, the ``clip`` state and ``highlight``: ``--time``,
    ``--objects``, ``--msaa``, ``--clip``, ``--highlight``) of the interactive frame
    (``--interactive``, at the levels of detail within ``lod_error_px``, a point cloud within
    ``point_budget`` points), or with ``still_samples``
    the progressive still of that many samples (``--samples N``; 0, ``ADAPTIVE``: ``--samples auto``);
    (h, w, 3) uint8. The same reference asked again (same arguments, the scene file unchanged) is
    rendered once per test run: render-once is exact, and parametrised tests share cameras."""
    scene_file = Path(scene)
    key = json.dumps([scene, [scene_file.stat().st_mtime_ns, scene_file.stat().st_size] if scene_file.is_file()
                      else None, camera, size, scene_time, objects, msaa, still_samples, clip, highlight,
                      lod_error_px, point_budget], sort_keys=True, default=lambda value: np.asarray(value).tolist())
    if key not in _REFERENCES:
        _REFERENCES[key] = _render_once(scene, camera, size, workdir, scene_time, objects, msaa, still_samples,
                                        clip, highlight, lod_error_px, point_budget)
    return _REFERENCES[key].copy()


#: References rendered in this test run, by their arguments (:func:`render_once`).
_REFERENCES: dict[str, np.ndarray] = {}


def _render_once(scene: str, camera: dict[str, Any], size: tuple[int, int], workdir: Path,
                 scene_time: float | None, objects: dict[str, Any] | None, msaa: int | None,
                 still_samples: int | None, clip: dict[str, Any] | None, highlight: str | None,
                 lod_error_px: float | None, point_budget: int | None) -> np.ndarray:
    index = len(list(workdir.glob("camera-*.json")))
    camera_file = workdir / f"camera-{index}.json"
    camera_file.write_text(json.dumps(camera))
    out = workdir / f"reference-{index}.png"
    extra = [] if scene_time is None else ["--time", repr(float(scene_time))]
    extra += [] if msaa is None else ["--msaa", str(msaa)]
    extra += ["--interactive"] if still_samples is None else ["--samples", str(still_samples or "auto")]
    extra += [] if lod_error_px is None else ["--lod-error-px", repr(float(lod_error_px))]
    extra += [] if point_budget is None else ["--point-budget", str(point_budget)]
    if objects is not None:
        objects_file = workdir / f"objects-{index}.json"
        objects_file.write_text(json.dumps(objects))
        extra += ["--objects", str(objects_file)]
    if clip is not None:
        clip_file = workdir / f"clip-{index}.json"
        clip_file.write_text(json.dumps(clip))
        extra += ["--clip", str(clip_file)]
    extra += [] if highlight is None else ["--highlight", highlight]
    result = subprocess.run(
        [PYTHON, "-m", "node", "--render-once", str(out), "--scene", scene, "--camera", str(camera_file),
         "--size", f"{size[0]}x{size[1]}", *extra],
        cwd=REPO, capture_output=True, text=True, timeout=seconds(180))
    assert result.returncode == 0, f"render-once failed:\n{result.stdout}\n{result.stderr}"
    return np.asarray(Image.open(out).convert("RGB"))


def assert_matches_reference(frame: np.ndarray, reference: np.ndarray, label: str) -> None:
    """PSNR ≥ 50 dB and no pixel off by more than 8 levels outside 0.01 % of pixels."""
    assert frame.shape == reference.shape, f"{label}: frame {frame.shape} vs reference {reference.shape}"
    quality = psnr(frame, reference)
    off = np.abs(frame.astype(np.int16) - reference.astype(np.int16)).max(axis=2) > 8
    assert quality >= 50.0, f"{label}: PSNR {quality:.1f} dB < 50"
    assert off.mean() <= 1e-4, f"{label}: {off.sum()} pixels off by > 8 levels"


def wait_until(condition: Callable[[], Any], timeout: float, what: str, interval: float = 0.1) -> Any:
    """Poll ``condition`` until it returns something truthy; fail naming ``what`` after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    last: Any = None
    while time.monotonic() < deadline:
        last = condition()
        if last:
            return last
        time.sleep(interval)
    raise AssertionError(f"timed out after {timeout:.0f}s waiting for {what}; last value: {last!r}")


def stats(client: httpx.Client) -> dict[str, Any]:
    return client.get("/api/stats").raise_for_status().json()


def ready_nodes(client: httpx.Client) -> list[dict[str, Any]]:
    return [n for n in stats(client)["nodes"] if n["state"] == "ready"]


def wait_ready_nodes(client: httpx.Client, count: int, timeout_s: float = 120.0) -> None:
    """Wait until ``count`` nodes are ready in ``/api/stats`` (a scaled ``timeout_s`` at most)."""
    wait_until(lambda: len(ready_nodes(client)) == count, seconds(timeout_s), f"{count} ready nodes")


def wait_rendering(client: httpx.Client, nodes: int) -> None:
    """Wait until ``nodes`` nodes are ready and the coordinator published a first frame."""
    wait_ready_nodes(client, nodes)
    wait_until(lambda: stats(client)["frame"] > 0, seconds(60), "a first frame")


def scene_bounds(client: httpx.Client) -> list[list[float]]:
    """The scene's bounds from ``GET /api/camera`` once the coordinator has them: [[x, y, z] lowest,
    [x, y, z] highest]."""
    return wait_until(lambda: client.get("/api/camera").json()["bounds"], seconds(60), "scene bounds")


def fetch_frame(client: httpx.Client, after: int) -> tuple[int, np.ndarray]:
    response = client.get("/api/frame.png", params={"after": after}, timeout=seconds(120))
    response.raise_for_status()
    return int(response.headers["x-frame-id"]), np.asarray(Image.open(io.BytesIO(response.content)).convert("RGB"))


def orbit_cameras(bounds: list[list[float]], count: int) -> list[dict[str, Any]]:
    """``count`` cameras around the scene's bounds at different angles, heights and distances."""
    lo, hi = np.asarray(bounds, dtype=float)
    center = (lo + hi) / 2
    radius = float(np.linalg.norm(hi - lo)) / 2
    cameras = []
    for i in range(count):
        angle = 0.7 + 2.1 * i
        distance = radius * (2.2 + 0.6 * (i % 2))
        eye = center + distance * np.array([np.sin(angle), 0.25 + 0.2 * i, np.cos(angle)])
        cameras.append({"eye": eye.tolist(), "target": center.tolist(), "up": [0, 1, 0], "fovy_deg": 40 + 5 * i})
    return cameras


@contextlib.contextmanager
def camera_moving(base_url: str, camera: dict[str, Any], hz: float = 30.0, token: str | None = None) -> Iterator[None]:
    """While inside, a user turns ``camera`` slowly (PUT /api/camera ``hz`` times a second, its own
    connection and thread): the coordinator keeps rendering, as it does only while input comes."""
    stop = threading.Event()
    headers = {"Authorization": f"Bearer {token}"} if token else {}

    def move() -> None:
        with httpx.Client(base_url=base_url, timeout=seconds(30), headers=headers) as client:
            step = 0
            while not stop.wait(1.0 / hz):
                client.put("/api/camera", json=orbit(camera, 0.02 * np.sin(step / 10.0))).raise_for_status()
                step += 1

    thread = threading.Thread(target=move, daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join(timeout=seconds(30))
