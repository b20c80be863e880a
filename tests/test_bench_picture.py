"""``python -m bench.picture`` end to end on a small built-in scene (real EGL rendering)."""

from __future__ import annotations

import json
import math

import pytest

from bench.picture import main

pytestmark = pytest.mark.gl


def test_picture_benchmark_reports_materials_and_antialiasing(tmp_path) -> None:
    """One camera of the spheres at auto (llvmpipe, a frame this small: the 4x4 grid of samples the
    reference draws, so it equals the reference), filter (one sample, filtered), 1 and 4 samples
    against the 4×4 supersampled frame: the filter and 4 samples come closer to it than one sample;
    the metal and dielectric spheres differ; times are positive."""
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
    assert (auto["grid"], auto["paired"], auto["filtered"]) == ([4, 4], False, False) and auto["psnr_mean_db"] > 60.0
    assert (filtered["paired"], filtered["filtered"], one["paired"], one["filtered"]) == (False, True, False, False)
    assert math.isfinite(one["psnr_mean_db"]) and four["psnr_mean_db"] > one["psnr_mean_db"] + 3.0
    assert auto["psnr_mean_db"] > filtered["psnr_mean_db"] > one["psnr_mean_db"] + 1.0
    assert four["off16_fraction"] < one["off16_fraction"]
    assert all(row["frame_ms"] > 0.0 and row["frame_cpu_ms"] > 0.0 for row in scene["rows"])
    (still,) = report["stills"]
    single, sixteen = still["rows"]
    assert (single["samples"], sixteen["samples"]) == (1, 16) and still["msaa"] >= 1
    # A frame this small draws the reference's 4x4 grid: one sample is the reference, 16 jittered stay near it.
    assert single["psnr_mean_db"] > 60.0 and sixteen["psnr_mean_db"] > 45.0
    assert sixteen["samples_mean"] == sixteen["samples_max"] == 16 and sixteen["still_ms"] > single["still_ms"] > 0.0
    assert all(still["coordinator"][key] > 0.0 for key in ("decode_ms", "accumulate_ms", "encode_ms",
                                                           "refinement_encode_ms"))
