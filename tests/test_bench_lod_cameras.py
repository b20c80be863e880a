"""bench.lod_cameras (issue 32) on the dragon: a row per camera, the levels drawing fewer triangles
than the model at a picture close to full detail, the silhouettes' share of the error a fraction,
each frame compared with the still too, the moving frame's JPEG against full detail's JPEG, the
error split by the kind of pixel it lies on, the worst camera of each figure, and the figures
written as JSON."""

from __future__ import annotations

import json

import pytest

from bench import lod_cameras
from bench.error_classes import CLASSES
from tessera.geometry import Camera
from tests.conftest import scene_path

DRAGON = "large_scan/stanford_dragon_vrip_res2_202k.ply"


@pytest.mark.gl
def test_lod_cameras_reports_each_camera_and_bound(ctx, tmp_path, capsys):
    out = tmp_path / "figures.json"
    assert lod_cameras.main(["--scene", str(scene_path(DRAGON)), "--cache-dir", str(tmp_path / "cache"),
                             "--size", "320x180", "--bounds", "1,3", "--orbit", "2", "--near", "1",
                             "--still-samples", "2", "--classes", "--json", str(out)]) == 0
    figures = json.loads(out.read_text())
    assert [row["camera"] for row in figures["cameras"]] == ["orbit 0°", "orbit 180°", "half 20°"]
    for row in figures["cameras"]:
        fine, coarse = row["1px"], row["3px"]
        assert 0 < coarse["triangles"] <= fine["triangles"] < 202_000
        assert fine["levels_db"] > 30.0 and row["codec_db"] > 25.0
        assert 0.0 <= fine["silhouette_share"] <= 1.0 and 0.0 < fine["silhouette_px"] < 0.2
        assert fine["still_db"] > 25.0 and row["full_still_db"] > 25.0
        assert fine["pipeline_db"] > 25.0
        classes = coarse["classes"]
        assert abs(sum(classes[name]["error"] for name in CLASSES) - 1.0) < 0.01
        assert classes["outline"]["pixels"] >= fine["silhouette_px"] and classes["facing"]["pixels"] > 0.0
        assert classes["model_db"] < coarse["levels_db"] and abs(classes["mean"]) < 5.0
    worst = figures["worst"]["3px"]["pipeline_db"]
    assert worst["db"] == min(row["3px"]["pipeline_db"] for row in figures["cameras"]) and worst["of"] == 3
    assert figures["worst"]["3px"]["max_triangles"] == max(row["3px"]["triangles"] for row in figures["cameras"])
    printed = capsys.readouterr().out
    assert "after JPEG" in printed and "JPEG against JPEG" in printed and "worst camera" in printed
    assert "depth_edge" in printed and "the model's pixels" in printed


def test_worst_names_the_worst_camera_and_counts_those_at_the_goal():
    rows = [{"camera": "a", "codec_db": 40.0, "1px": {"triangles": 5, "levels_db": 41.0, "pipeline_db": 37.5}},
            {"camera": "b", "codec_db": 36.0, "1px": {"triangles": 9, "levels_db": 39.0, "pipeline_db": 38.5}},
            {"camera": "c", "codec_db": 45.0, "1px": {"triangles": 7, "levels_db": 38.0, "pipeline_db": 39.0}}]
    worst = lod_cameras.worst(rows)
    assert worst["codec_db"] == {"db": 36.0, "camera": "b", "at_goal": 2, "of": 3}
    assert worst["1px"]["levels_db"] == {"db": 38.0, "camera": "c", "at_goal": 3, "of": 3}
    assert worst["1px"]["pipeline_db"] == {"db": 37.5, "camera": "a", "at_goal": 2, "of": 3}
    assert worst["1px"]["max_triangles"] == 9 and "moving_db" not in worst["1px"]
    assert "pipeline_db  37.5 dB (a), 2/3 cameras >= 38" in lod_cameras.report_worst(worst)


def test_cameras_around_turns_the_base_camera_and_comes_half_as_near():
    base = Camera(eye=(0.0, 1.0, 4.0), target=(0.0, 1.0, 0.0))
    named = lod_cameras.cameras_around(base, 4, 1)
    assert [name for name, _ in named] == ["orbit 0°", "orbit 90°", "orbit 180°", "orbit 270°", "half 20°"]
    assert named[0][1].eye == base.eye
    assert abs(named[2][1].eye[2] + 4.0) < 1e-6
    near = named[4][1]
    assert abs(sum((e - t) ** 2 for e, t in zip(near.eye, near.target, strict=True)) ** 0.5 - 2.0) < 1e-6
