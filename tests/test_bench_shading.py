"""``python -m bench.shading`` end to end on a small built-in scene (real EGL rendering, two trees)."""

from __future__ import annotations

import json

import pytest

from bench.shading import LAMBERT_REVISION, THIS_TREE, main

pytestmark = pytest.mark.gl


def test_shading_cost_benchmark_times_this_tree_against_the_lambert_one(tmp_path) -> None:
    """This tree and the one before physically based shading each render the spheres in their own
    process: both timed, the ratio theirs, and the pictures differ (the shading changed)."""
    out = tmp_path / "shading.json"
    argv = ["--scene", "builtin:spheres", "--size", "64x48", "--frames", "2", "--rounds", "1", "--json", str(out)]
    assert main(argv) == 0
    report = json.loads(out.read_text())
    assert report["baselines"] == [LAMBERT_REVISION] and report["meta"]["argv"] == argv
    (row,) = report["rows"]
    assert row["scene"] == "builtin:spheres"
    for name in (THIS_TREE, LAMBERT_REVISION):
        assert row[name]["wall_ms"] > 0.0 and row[name]["cpu_ms"] > 0.0
    assert row["ratio_wall"] == pytest.approx(row[THIS_TREE]["wall_ms"] / row[LAMBERT_REVISION]["wall_ms"])
    assert 5.0 < row[LAMBERT_REVISION]["psnr_db"] < 40.0
