"""``python -m bench.culling`` end to end on a small built-in scene (real EGL rendering)."""

from __future__ import annotations

import json

import pytest

from bench.culling import main
from tests.bench_support import orbit_path

pytestmark = pytest.mark.gl


def test_culling_benchmark_reports_its_figures(tmp_path, monkeypatch, capsys) -> None:
    """Two frames of an orbit of the spheres as 4 tiles: culled tiles are identical to the unculled
    frame, they submit no fewer triangles than the whole culled frame, and culling on the CPU draws
    fewer chunks than there are; the report names the llvmpipe thread count it ran with."""
    monkeypatch.setenv("LP_NUM_THREADS", "1")
    path = orbit_path(tmp_path, "builtin:spheres")
    out = tmp_path / "culling.json"
    assert main(["--scene", "builtin:spheres", "--path", str(path), "--tiles", "4", "--size", "160x120",
                 "--face-limit", "64", "--culling", "cpu", "--repeats", "1", "--frames", "2",
                 "--json", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["frames"] == 2 and report["tiles"] == 4 and report["lp_num_threads"] == "1"
    assert report["culling"] == "cpu" and report["culling_asked"] == "cpu"
    assert report["psnr_min"] >= 50.0 and report["redundancy"] >= 1.0
    assert report["cull_speedup"] > 0.0 and set(report["cull_speedup_by_mode"]) >= {"cpu", "gpu", "hybrid"}
    assert report["modes"]["cpu"]["chunks_drawn_per_tile"] < report["chunks"]
    assert "LP_NUM_THREADS 1" in capsys.readouterr().out


def test_culling_benchmark_plays_an_animation_along_the_path(tmp_path, capsys) -> None:
    """``--time-per-frame``: the traffic's cars move between the frames and the tiles still equal the frame."""
    path = orbit_path(tmp_path, "builtin:traffic")
    out = tmp_path / "culling.json"
    assert main(["--scene", "builtin:traffic", "--path", str(path), "--tiles", "4", "--size", "160x120",
                 "--culling", "cpu", "--repeats", "1", "--frames", "2", "--time-per-frame", "2.5",
                 "--start-time", "1", "--json", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["scene_times"] == [1.0, 18.5]
    assert report["psnr_min"] >= 50.0 and report["redundancy"] >= 1.0
    assert "animation played along the path: scene time 1 .. 18.5 s" in capsys.readouterr().out
