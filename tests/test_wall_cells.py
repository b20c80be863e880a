"""A display wall's geometry (issue 22): its size with bezels, cell rects, a partition cut at the
cell edges (exact cover, every piece inside one cell or the bezel), a cell's tiles relative to
it, and bad parameters refused with the reason."""

from __future__ import annotations

import numpy as np
import pytest

from tessera.balancers.base import Partition, Tile
from tessera.balancers.partition import check_exact_cover
from tessera.decomposition.wall_cells import WallError, WallLayout, parse_cell
from tessera.geometry import Rect

WALL = WallLayout(2, 2, (640, 360), (20, 10))


def test_a_wall_is_its_cells_and_bezels():
    assert WALL.size == (2 * 640 + 20, 2 * 360 + 10)
    assert WALL.cell_rect(0, 0) == Rect(0, 0, 640, 360)
    assert WALL.cell_rect(1, 1) == Rect(660, 370, 640, 360)
    assert WALL.cells == [(0, 0), (1, 0), (0, 1), (1, 1)]
    assert WallLayout(3, 1, (100, 50)).size == (300, 50)


def test_a_cut_partition_covers_the_wall_with_every_piece_in_one_cell_or_the_bezel():
    width, height = WALL.size
    # three vertical strips and a horizontal one, straddling both cell edges and both bezels
    tiles = (Tile(Rect(0, 0, 500, 600), 1), Tile(Rect(500, 0, 300, 600), 2), Tile(Rect(800, 0, width - 800, 600), 3),
             Tile(Rect(0, 600, width, height - 600), 1))
    cut = WALL.cut(Partition(tiles))
    check_exact_cover(cut.rects, WALL.size)
    owner = np.zeros((height, width), np.int64)
    for tile in tiles:
        owner[tile.rect.y:tile.rect.y1, tile.rect.x:tile.rect.x1] = tile.node_id
    cells = [WALL.cell_rect(c, r) for c, r in WALL.cells]
    for tile in cut.tiles:
        r = tile.rect
        assert (owner[r.y:r.y1, r.x:r.x1] == tile.node_id).all()   # a piece keeps its tile's node
        inside = [c for c in cells if c.x <= r.x and r.x1 <= c.x1 and c.y <= r.y and r.y1 <= c.y1]
        touching = [c for c in cells if c.intersection_area(r) > 0]
        assert len(inside) == 1 or not touching, r   # inside one cell, or all in the bezel
    in_cells = sum(len(WALL.in_cell(cut.rects, c, r)) for c, r in WALL.cells)
    bezel = [t for t in cut.tiles if all(c.intersection_area(t.rect) == 0 for c in cells)]
    assert in_cells + len(bezel) == len(cut.tiles)


def test_without_bezels_no_piece_is_empty():
    wall = WallLayout(2, 2, (160, 120))
    cut = wall.cut(Partition((Tile(Rect(0, 0, 100, 240), 1), Tile(Rect(100, 0, 220, 240), 2))))
    check_exact_cover(cut.rects, wall.size)
    assert all(t.rect.w > 0 and t.rect.h > 0 for t in cut.tiles)
    assert len(cut.tiles) == 6


def test_a_tile_inside_one_cell_is_kept_and_a_pull_list_keeps_its_order():
    tiles = (Tile(Rect(0, 0, 640, 360), None), Tile(Rect(640, 0, 660, 730), None), Tile(Rect(0, 360, 640, 370), None))
    cut = WALL.cut(Partition(tiles, pull=True))
    assert cut.pull and cut.tiles[0] == tiles[0]
    assert [t.rect for t in cut.tiles[1:]] == [
        Rect(640, 0, 20, 360), Rect(660, 0, 640, 360), Rect(640, 360, 20, 10), Rect(660, 360, 640, 10),
        Rect(640, 370, 20, 360), Rect(660, 370, 640, 360), Rect(0, 360, 640, 10), Rect(0, 370, 640, 360)]


def test_a_cells_tiles_are_relative_to_the_cell():
    rects = [Rect(660, 370, 300, 360), Rect(960, 370, 340, 360), Rect(0, 0, 640, 360), Rect(640, 0, 20, 730)]
    assert WALL.in_cell(rects, 1, 1) == [(0, Rect(0, 0, 300, 360)), (1, Rect(300, 0, 340, 360))]
    assert WALL.in_cell(rects, 0, 0) == [(2, Rect(0, 0, 640, 360))]
    assert WALL.in_cell(rects, 1, 0) == []


@pytest.mark.parametrize(("cols", "rows", "cell", "bezel", "why"), [
    (0, 2, [64, 48], None, "at least one cell"),
    (2, 0, [64, 48], None, "at least one cell"),
    (9, 9, [64, 48], None, "at most 64 cells"),
    (2, 2, [0, 48], None, "at least 1x1"),
    (2, 2, [300, 48], None, "larger than the largest frame"),
    (2, 2, [64, 48], [-1, 0], "at least 0 px"),
    (2, 2, [64.5, 48], None, "whole numbers"),
    (8, 8, [200, 100], None, "pixel budget"),
])
def test_bad_walls_are_refused_with_the_reason(cols, rows, cell, bezel, why):
    with pytest.raises(WallError, match=why):
        WallLayout.checked(cols, rows, cell, bezel, largest_cell=(200, 100), most_pixels=4 * 200 * 100)


def test_a_wall_over_the_gl_limit_is_refused():
    with pytest.raises(WallError, match="16384 px a side"):
        WallLayout.checked(8, 1, [3840, 2160])


def test_walls_round_trip_json_and_cells_parse():
    assert WallLayout.from_json(WALL.to_json()) == WALL
    assert WallLayout.from_json({"cols": 1, "rows": 2, "cell": [10, 20]}) == WallLayout(1, 2, (10, 20))
    with pytest.raises(WallError):
        WallLayout.from_json({"cols": 1})
    assert parse_cell("1,0") == (1, 0)
    for bad in ("1", "a,b", "-1,0", "1,2,3", ""):
        with pytest.raises(WallError, match="COL,ROW"):
            parse_cell(bad)
    with pytest.raises(WallError, match="outside the wall"):
        WALL.cell_rect(2, 0)
