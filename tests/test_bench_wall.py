"""The wall benchmark end to end (a real coordinator, real nodes, scripted cells and driver) on a
small run; speeds are reported, never asserted: only that the figures exist and make sense."""

from __future__ import annotations

import json

import pytest

from bench.wall import main

pytestmark = [pytest.mark.integration, pytest.mark.gl]


def test_wall_bench_end_to_end(tmp_path):
    out = tmp_path / "wall.json"
    assert main(["--cols", "2", "--rows", "1", "--cell", "96x64", "--bezel", "4x0", "--nodes", "2",
                 "--scene", "builtin:spheres", "--moving-s", "3", "--json", str(out)]) == 0
    result = json.loads(out.read_text())
    wall, single = result["wall"], result["single"]
    assert wall["size"] == [196, 64] and single["size"] == [196, 64]
    assert wall["presented_fps"] > 0 and wall["driver_fps"] > 0 and single["fps"] > 0
    assert wall["skew_samples"] >= 1 and 0.0 <= wall["skew_p50_ms"] <= wall["skew_p99_ms"]
    assert result["fps_ratio"] > 0 and result["cells_are"] == "scripted"
