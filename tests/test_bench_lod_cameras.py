"""bench.lod_cameras (issue 32) on the dragon: a row per camera, the levels drawing fewer triangles
than the model at a picture close to full detail, the silhouettes' share of the error a fraction,
each frame compared with the still too, and the figures written as JSON."""

from __future__ import annotations

import json

import pytest

from bench import lod_cameras
from tests.conftest import scene_path

DRAGON = "large_scan/stanford_dragon_vrip_res2_202k.ply"


@pytest.mark.gl
def test_lod_cameras_reports_each_camera_and_bound(ctx, tmp_path, capsys):
    out = tmp_path / "figures.json"
    assert lod_cameras.main(["--scene", str(scene_path(DRAGON)), "--cache-dir", str(tmp_path / "cache"),
                             "--size", "320x180", "--bounds", "1,3", "--orbit", "2", "--near", "1",
                             "--still-samples", "2", "--json", str(out)]) == 0
    figures = json.loads(out.read_text())
    assert [row["camera"] for row in figures["cameras"]] == ["orbit 0°", "orbit 180°", "half 20°"]
    for row in figures["cameras"]:
        fine, coarse = row["1px"], row["3px"]
        assert 0 < coarse["triangles"] <= fine["triangles"] < 202_000
        assert fine["levels_db"] > 30.0 and row["codec_db"] > 25.0
        assert 0.0 <= fine["silhouette_share"] <= 1.0 and 0.0 < fine["silhouette_px"] < 0.2
        assert fine["still_db"] > 25.0 and row["full_still_db"] > 25.0
    assert "after JPEG" in capsys.readouterr().out
