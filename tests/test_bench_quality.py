"""``python -m bench.quality`` end to end on a small built-in scene (real EGL rendering)."""

from __future__ import annotations

import json
import math

import pytest

from bench.quality import main
from tests.bench_support import orbit_path

pytestmark = pytest.mark.gl


def test_quality_benchmark_reports_bytes_against_psnr(tmp_path, capsys) -> None:
    """Two frames of an orbit of the spheres at three JPEG qualities: PSNR and bytes grow with
    quality, 4:4:4 chroma starts at q90, PNG and RAW decode to the rendered pixels, every size and
    time is positive and finite, and the 35/40 dB marks are the smallest qualities reaching them."""
    path = orbit_path(tmp_path, "builtin:spheres")
    out = tmp_path / "quality.json"
    argv = ["--scene", "builtin:spheres", "--path", str(path), "--size", "160x120", "--frames", "2",
            "--qualities", "20,60,95", "--json", str(out)]
    assert main(argv) == 0
    report = json.loads(out.read_text())
    meta = report["meta"]
    assert meta["scenes"] == ["builtin:spheres"] and meta["size"] == [160, 120] and meta["argv"] == argv
    assert meta["renderer"] and meta["python"]
    (scene,) = report["scenes"]
    assert scene["frames"] == 2
    rows = {row["setting"]: row for row in scene["rows"]}
    assert list(rows) == ["jpeg q20", "jpeg q60", "jpeg q95", "png", "raw"]
    jpeg = [rows["jpeg q20"], rows["jpeg q60"], rows["jpeg q95"]]
    assert [row["chroma"] for row in jpeg] == ["4:2:0", "4:2:0", "4:4:4"]
    psnr = [row["psnr_mean_db"] for row in jpeg]
    kb = [row["kb_mean"] for row in jpeg]
    assert psnr == sorted(psnr) and len(set(psnr)) == 3 and all(math.isfinite(p) and p > 20.0 for p in psnr)
    assert kb == sorted(kb) and len(set(kb)) == 3
    assert all(not row["lossless"] and 0 < row["psnr_min_db"] <= row["psnr_mean_db"] for row in jpeg)
    assert jpeg[0]["off8_fraction"] >= jpeg[2]["off8_fraction"] and jpeg[0]["max_error"] > 0
    for name in ("png", "raw"):
        assert rows[name]["lossless"] and rows[name]["max_error"] == 0 and rows[name]["off8_fraction"] == 0.0
        assert rows[name]["psnr_mean_db"] is None and rows[name]["psnr_min_db"] is None
    assert rows["raw"]["kb_mean"] == 160 * 120 * 3 / 1e3 > rows["png"]["kb_mean"]
    for name, row in rows.items():
        assert all(math.isfinite(row[key]) and row[key] > 0 for key in ("kb_mean", "mbit_s_30fps"))
        assert row["mbit_s_30fps"] == pytest.approx(row["kb_mean"] * 8e3 * 30 / 1e6, abs=0.01)
        assert all(math.isfinite(row[key]) and row[key] >= 0 for key in ("encode_ms", "decode_ms"))
        assert name == "raw" or row["encode_ms"] > 0
    for mark in (35, 40):
        reached = [row["quality"] for row in jpeg if row["psnr_mean_db"] >= mark]
        assert scene[f"quality_for_{mark}db"] == (reached[0] if reached else None)
    printed = capsys.readouterr().out
    assert "lossless" in printed and "jpeg q60" in printed and "smallest JPEG quality" in printed


def test_quality_benchmark_rejects_unpaired_paths() -> None:
    """Three --path for two scenes is a usage error (one serves all scenes, or one per scene)."""
    with pytest.raises(SystemExit):
        main(["--scene", "builtin:spheres", "--scene", "builtin:cluster", "--path", "orbit", "--path", "zoom",
              "--path", "orbit"])


def test_quality_benchmark_measures_antialiasing_and_the_still(tmp_path, capsys) -> None:
    """Issue 20's figures from ``bench.quality``: at a camera of the scene's path, the interactive
    frame of each ``--msaa`` setting and the still of each sample count against the 4×4
    supersampled frame, with their times; anti-aliasing comes closer to it, and the still (at this
    size the reference's own grid, jittered) stays near it."""
    path = orbit_path(tmp_path, "builtin:spheres")
    out = tmp_path / "quality.json"
    argv = ["--scene", "builtin:spheres", "--path", str(path), "--size", "96x72", "--frames", "1",
            "--qualities", "60", "--msaa", "auto,1", "--still-samples", "1,8", "--picture-frames", "1",
            "--json", str(out)]
    assert main(argv) == 0
    (scene,) = json.loads(out.read_text())["scenes"]
    auto, one = scene["antialiasing"]["rows"]
    assert (auto["msaa"], one["msaa"], scene["antialiasing"]["frames"]) == (0, 1, 1)
    assert auto["psnr_mean_db"] > one["psnr_mean_db"] + 1.0 and auto["frame_ms"] > 0.0 < one["frame_ms"]
    single, eight = scene["still"]["rows"]
    assert (single["samples"], eight["samples"]) == (1, 8) and min(single["psnr_mean_db"], eight["psnr_mean_db"]) > 45.0
    assert eight["samples_mean"] == eight["samples_max"] == 8 and eight["still_ms"] > single["still_ms"] > 0.0
    printed = capsys.readouterr().out
    assert "auto " in printed and "progressive still" in printed


def test_quality_benchmark_over_random_cameras_and_sizes_reports_the_worst_case(tmp_path, capsys) -> None:
    """``--cameras N --sizes``: N seeded random cameras per scene at each size (the same cameras on
    a second run), the adaptive still's samples, and a summary of the worst PSNR beside the mean."""
    out = tmp_path / "quality.json"
    argv = ["--scene", "builtin:spheres", "--cameras", "2", "--seed", "3", "--sizes", "96x54,128x72",
            "--qualities", "none", "--msaa", "auto", "--still-samples", "auto", "--json", str(out)]
    assert main(argv) == 0
    report = json.loads(out.read_text())
    assert report["meta"]["cameras"] == 2 and report["meta"]["sizes"] == [[96, 54], [128, 72]]
    small, large = report["scenes"]
    assert (small["size"], large["size"]) == ([96, 54], [128, 72]) and small["rows"] == []
    (adaptive,) = small["still"]["rows"]
    assert adaptive["adaptive"] and 1 <= adaptive["samples_mean"] <= adaptive["samples_max"] <= 64
    assert adaptive["estimate_min_db"] is not None
    summary = {(entry["setting"], entry["size"]): entry for entry in report["summary"]}
    assert set(summary) == {("interactive auto 4x4", "96x54"), ("interactive auto 4x4", "128x72"),
                            ("still auto", "96x54"), ("still auto", "128x72")}
    for (setting, size), entry in summary.items():
        scene = small if size == "96x54" else large
        rows = scene["antialiasing" if setting.startswith("interactive") else "still"]["rows"]
        assert entry["psnr_worst_db"] == rows[0]["psnr_min_db"] <= entry["psnr_mean_db"]
    assert summary["still auto", "96x54"]["samples_max"] == adaptive["samples_max"]
    assert "worst case over scenes and cameras" in capsys.readouterr().out
    again = tmp_path / "again.json"
    assert main([*argv[:-1], str(again)]) == 0
    def pictures(summary: list[dict]) -> list[tuple]:
        return [(e["setting"], e["size"], e["psnr_mean_db"], e["psnr_worst_db"], e.get("samples_max")) for e in summary]

    assert pictures(json.loads(again.read_text())["summary"]) == pictures(report["summary"]), "seeded: the same cameras"
