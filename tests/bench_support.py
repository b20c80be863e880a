"""What the benchmark tests share: a short camera path on disk, where a benchmark's ``--path`` reads it."""

from __future__ import annotations

import json
from pathlib import Path

from bench.paths import make_path
from node.scene.loading import load_scene


def orbit_path(folder: Path, scene: str, frames: int = 8) -> Path:
    """``folder``/orbit.json: :func:`bench.paths.make_path`'s orbit of ``frames`` cameras around
    ``scene`` (a scene file or ``builtin:NAME``)."""
    path = folder / "orbit.json"
    path.write_text(json.dumps(make_path("orbit", load_scene(scene).bounds, frames=frames)))
    return path
