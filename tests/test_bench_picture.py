"""``python -m bench.picture`` end to end on a small built-in scene (real EGL rendering)."""

from __future__ import annotations

import json
import math

import pytest

from bench.picture import main

pytestmark = pytest.mark.gl


def test_picture_benchmark_reports_materials_and_antialiasing(tmp_path) -> None:
    """One camera of the spheres at auto (llvmpipe: two samples drawn twice as wide, filtered),
    filter (one sample, filtered), 1 and 4 samples against the 4×4 supersampled frame: the filters
    and 4 samples come closer to it, the second sample closer than the filter alone; the metal and
    dielectric spheres differ; times are positive."""
    out = tmp_path / "picture.json"
    argv = ["--scene", "builtin:spheres", "--size", "96x72", "--frames", "1", "--msaa", "auto,filter,1,4",
            "--still-samples", "1,16", "--material-size", "64x64", "--json", str(out)]
    assert main(argv) == 0
    report = json.loads(out.read_text())
    assert report["meta"]["argv"] == argv and report["environment_ms"] > 0.0
    materials = report["materials"]
    assert 0.0 < materials["spread_ratio"] < 0.8 and materials["colour_distance"] > 30.0
    (scene,) = report["scenes"]
    auto, filtered, one, four = scene["rows"]
    assert [row["msaa"] for row in scene["rows"]] == [0, -1, 1, 4] and scene["frames"] == 1
    assert (auto["samples"], auto["paired"], auto["filtered"]) == (1, True, True)
    assert (filtered["paired"], filtered["filtered"], one["paired"], one["filtered"]) == (False, True, False, False)
    assert math.isfinite(one["psnr_mean_db"]) and four["psnr_mean_db"] > one["psnr_mean_db"] + 3.0
    assert auto["psnr_mean_db"] > filtered["psnr_mean_db"] > one["psnr_mean_db"] + 1.0
    assert four["off16_fraction"] < one["off16_fraction"]
    assert all(row["frame_ms"] > 0.0 and row["frame_cpu_ms"] > 0.0 for row in scene["rows"])
    (still,) = report["stills"]
    single, sixteen = still["rows"]
    assert (single["samples"], sixteen["samples"]) == (1, 16) and still["msaa"] >= 1
    assert sixteen["psnr_mean_db"] > single["psnr_mean_db"] + 3.0, "the progressive still nears the reference"
    assert sixteen["samples_mean"] == sixteen["samples_max"] == 16 and sixteen["still_ms"] > single["still_ms"] > 0.0
    assert all(still["coordinator"][key] > 0.0 for key in ("decode_ms", "accumulate_ms", "encode_ms",
                                                           "refinement_encode_ms"))
