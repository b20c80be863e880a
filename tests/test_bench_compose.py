"""``python -m bench.compose`` end to end on a small built-in scene (real EGL rendering): every mode
composes the reference exactly, sort-last draws each triangle in view once from a quarter of the
scene per node, the hybrid draws no more than sort-first, and the figures the issue names are there."""

from __future__ import annotations

import json

import pytest

from bench.compose import main
from tests.bench_support import orbit_path

pytestmark = pytest.mark.gl


def test_compose_benchmark_reports_its_figures(tmp_path, monkeypatch, capsys) -> None:
    monkeypatch.setenv("LP_NUM_THREADS", "0")
    path = orbit_path(tmp_path, "builtin:spheres")
    out = tmp_path / "compose.json"
    assert main(["--scene", "builtin:spheres", "--path", str(path), "--tiles", "4", "--size", "160x120",
                 "--modes", "sort-first,hybrid,sort-last", "--strips", "0,8", "--nodes", "4", "--face-limit", "64",
                 "--frames", "2", "--json", str(out)]) == 0
    report = json.loads(out.read_text())
    modes = report["modes"]
    assert set(modes) == {"sort-first", "hybrid", "hybrid:0", "hybrid:8", "sort-last"}
    for row in modes.values():
        assert row["psnr_min"] == 100.0
        assert {"redundancy", "bytes_per_frame", "compose_ms", "node_triangle_fraction"} <= set(row)
        assert row["bytes_per_frame"] > 0 and row["compose_ms"] >= 0.0
    assert modes["sort-last"]["redundancy"] == 1.0
    assert modes["sort-last"]["node_triangle_fraction"] < 0.5 and sum(report["share_triangles"]) == report["triangles"]
    assert modes["hybrid"]["redundancy"] <= modes["sort-first"]["redundancy"]
    assert modes["hybrid:0"]["redundancy"] >= modes["hybrid:8"]["redundancy"] >= 1.0
    assert modes["sort-first"]["depth_bytes"] == 0 < modes["hybrid"]["depth_bytes"] < modes["hybrid"]["bytes_per_frame"]
    assert modes["sort-first"]["node_triangle_fraction"] == 1.0
    assert "node_triangle_fraction" in capsys.readouterr().out
