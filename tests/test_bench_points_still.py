"""bench.points_still (issue 36): the still at a spacing on screen against the still of every point,
in one process, on a small LAZ terrain."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench import points_still
from bench.points import write_terrain

pytestmark = pytest.mark.gl


def test_the_still_at_each_spacing_is_drawn_against_the_still_of_every_point(tmp_path: Path) -> None:
    cloud = write_terrain(tmp_path / "terrain.laz", 60_000)
    out = tmp_path / "still.json"
    assert (
        points_still.main(
            [
                "--cloud",
                str(cloud),
                "--cache",
                str(tmp_path / "cache"),
                "--size",
                "64x40",
                "--samples",
                "2",
                "--spacings",
                "0,4",
                "--paths",
                "oblique",
                "--json",
                str(out),
            ]
        )
        == 0
    )
    rows = json.loads(out.read_text())["rows"]
    assert [row["spacing_px"] for row in rows] == [0.0, 4.0]
    every, coarse = rows
    assert every["points"] == every["every_points"] > 0 and every["psnr_db"] == 100.0  # the same still
    assert 0 < coarse["points"] < every["points"] and coarse["psnr_db"] < 100.0
