"""A fresh process that loads one scene (or sort-last share) as a node does, draws one tile of it and
prints its memory as JSON (resident MiB before, once loaded, its peak while loading, once drawn, its
peak over all): ``python -m tests.memory_probe SPEC CACHE_DIR [INDEX WEIGHT,WEIGHT,...]``
(the scene memory tests measure what a node holds, apart from the test process)."""

from __future__ import annotations

import asyncio
import json
import sys
from pathlib import Path

from node.gl.worker import GLWorker
from node.scene.cache_folder import CacheFolder
from node.scene.pages import resident_mb
from tessera.geometry import Rect, default_camera
from tessera.wire.messages import DepthRequest, LoadScene, ShareSpec


def peak_mb() -> float:
    """This process's peak resident memory (VmHWM), MiB."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return 0.0


async def probe(spec: str, cache: Path, share: ShareSpec | None) -> dict[str, float]:
    worker = GLWorker(cache=CacheFolder(cache), read_in_process_bytes=1 << 62)
    await worker.start()
    try:
        before = resident_mb()
        loaded = await worker.load(LoadScene(scene=spec, share=share), lambda fraction, message: None)
        loaded_mb, loading_peak_mb = resident_mb(), peak_mb()
        size = (160, 120)
        camera = default_camera(loaded.scene.bounds, aspect=size[0] / size[1])
        if share is None:
            await worker.render(camera, size, Rect(0, 0, *size), 0, scene=spec)
        else:
            request = DepthRequest(mode="sort-last", share=share.version)
            await worker.render_depth(camera, size, request, 0, None, spec)
        geometry = loaded.scene.geometry
        return {"before_mb": before, "loaded_mb": loaded_mb, "loading_peak_mb": loading_peak_mb,
                "drawn_mb": resident_mb(), "peak_mb": peak_mb(),
                "gpu_mb": 0.0 if geometry is None else geometry.nbytes / (1 << 20),
                "scene_mb": loaded.nbytes / (1 << 20),
                "triangles": loaded.scene.triangle_count}
    finally:
        await asyncio.to_thread(worker.close)


if __name__ == "__main__":
    spec, cache = sys.argv[1], Path(sys.argv[2])
    share = None if len(sys.argv) < 4 else ShareSpec(version=1, index=int(sys.argv[3]),
                                                      weights=tuple(float(w) for w in sys.argv[4].split(",")))
    print(json.dumps(asyncio.run(probe(spec, cache, share))))
