"""Hybrid chunk ownership as a pure function (seed 000 §4.4): one owner per chunk, drawn beyond its
tile's edge into the strip, larger chunks shared by every tile they touch, off-screen chunks drawn
by nobody, read-back rects clipped to the frame, and every pixel a chunk can write lies in a layer
that draws it."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tessera.balancers.partition import equal_strip_partition
from tessera.decomposition.chunk_ownership import (
    OFF_SCREEN,
    SHARED,
    assign_chunks,
    core_rect,
    exclusive_rect,
    readback_rect,
)
from tessera.geometry import Rect

SIZE = (200, 100)
#: two tiles side by side, cut at x = 120
TILES = [Rect(0, 0, 120, 100), Rect(120, 0, 80, 100)]


def owners(bounds, strip=8, tiles=TILES, size=SIZE):
    return assign_chunks(np.asarray(bounds, np.float64), tiles, strip, size).owner.tolist()


def test_a_chunk_inside_one_tile_is_owned_by_it():
    assert owners([[10, 10, 30, 40], [150, 60, 190, 90]]) == [0, 1]


def test_a_chunk_straddling_an_edge_by_less_than_the_strip_goes_to_the_tile_holding_its_centre():
    # centre at x 116 (tile 0), reaching 6 px into tile 1: the strip (8) + margin (1) holds it
    assert owners([[100, 10, 126, 20]]) == [0]
    # centre at x 123 (tile 1), reaching 6 px back into tile 0
    assert owners([[114, 10, 132, 20]]) == [1]


def test_a_chunk_wider_than_the_strip_is_shared_and_drawn_by_every_tile_it_touches():
    result = assign_chunks(np.array([[100, 10, 140, 20.0]]), TILES, 8, SIZE)
    assert result.owner.tolist() == [SHARED]
    assert [d.tolist() for d in result.draws] == [[0], [0]]


def test_a_tile_a_blended_chunk_touches_is_drawn_complete_and_all_of_it_is_its_core():
    """Blended chunks write no depth: the tiles they touch draw every chunk touching them (the
    ones the neighbour owns too), and their whole rect is final as drawn."""
    bounds = np.array([[100, 10, 126, 20], [150, 60, 170, 80], [10, 10, 30, 40.0]])
    result = assign_chunks(bounds, TILES, 8, SIZE, blended=np.array([False, True, False]))
    assert result.owner.tolist() == [0, 1, 0]
    assert result.complete.tolist() == [False, True]
    assert [d.tolist() for d in result.draws] == [[0, 2], [0, 1]]
    assert core_rect(TILES[1], 8, SIZE, complete=True) == TILES[1]
    assert core_rect(TILES[0], 8, SIZE) == exclusive_rect(TILES[0], 8, SIZE)
    assert not assign_chunks(bounds, TILES, 8, SIZE).complete.any()


def test_strip_zero_owns_only_chunks_inside_a_tile():
    assert owners([[10, 10, 30, 40], [100, 10, 126, 20]], strip=0) == [0, SHARED]


def test_the_margin_keeps_a_chunk_ending_on_the_edge_from_counting_as_inside():
    # a bound ending exactly at x = 120 can still light pixel 119 and, by float32 rounding, 120
    assert owners([[100, 10, 120, 20]], strip=0) == [SHARED]
    assert owners([[100, 10, 118.5, 20]], strip=0) == [0]


def test_chunks_against_the_frame_edge_fit_with_no_strip():
    assert owners([[0, 0, 20, 100], [180, 0, 200, 100]], strip=0) == [0, 1]


def test_off_screen_chunks_are_drawn_by_nobody():
    result = assign_chunks(np.array([[0, 0, 0, 0], [50, 50, 50, 70.0], [10, 10, 20, 20]]), TILES, 8, SIZE)
    assert result.owner.tolist() == [OFF_SCREEN, OFF_SCREEN, 0]
    assert [d.tolist() for d in result.draws] == [[2], []]


def test_a_centre_tile_too_narrow_hands_the_chunk_to_a_tile_whose_strip_holds_it():
    # a 6 px wide tile 1 over a full-width tile 3; strip 4
    tiles = [Rect(0, 0, 100, 50), Rect(100, 0, 6, 50), Rect(106, 0, 94, 50), Rect(0, 50, 200, 50)]
    # centre (105, 49.5) lies in tile 1, whose read-back rect [96, 110) cannot hold x [94, 116] (margin
    # included); tile 3's [0, 200) × [46, 100) can
    assert owners([[95, 47, 115, 52]], strip=4, tiles=tiles) == [3]
    assert owners([[101, 47, 105, 52]], strip=4, tiles=tiles) == [1]


def test_no_chunks_and_empty_draw_lists():
    result = assign_chunks(np.zeros((0, 4)), TILES, 8, SIZE)
    assert result.owner.shape == (0,) and all(d.size == 0 for d in result.draws)


def test_readback_rect_is_the_tile_grown_by_the_strip_and_clipped():
    assert readback_rect(Rect(120, 0, 80, 100), 8, SIZE) == Rect(112, 0, 88, 100)
    assert readback_rect(Rect(50, 30, 20, 20), 8, SIZE) == Rect(42, 22, 36, 36)
    assert readback_rect(Rect(50, 30, 20, 20), 0, SIZE) == Rect(50, 30, 20, 20)
    result = assign_chunks(np.zeros((0, 4)), TILES, 8, SIZE)
    assert result.readback == (Rect(0, 0, 128, 100), Rect(112, 0, 88, 100))


def test_bad_arguments_are_refused():
    with pytest.raises(ValueError, match="strip"):
        assign_chunks(np.zeros((1, 4)), TILES, -1, SIZE)
    with pytest.raises(ValueError, match="tile"):
        assign_chunks(np.zeros((1, 4)), [], 8, SIZE)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), tiles=st.integers(1, 16), strip=st.sampled_from([0, 2, 8, 32]))
def test_every_pixel_of_every_chunk_lies_in_a_layer_that_draws_it(seed, tiles, strip):
    rng = np.random.default_rng(seed)
    size = (160, 90)
    rects = equal_strip_partition(tiles, size)
    lo = rng.uniform(-20, [170, 100], (40, 2))
    bounds = np.concatenate([lo, lo + rng.uniform(0, 60, (40, 2)) ** rng.uniform(0.5, 1.2, (40, 2))], axis=1)
    bounds[:, [0, 2]] = np.clip(bounds[:, [0, 2]], 0, size[0])
    bounds[:, [1, 3]] = np.clip(bounds[:, [1, 3]], 0, size[1])
    result = assign_chunks(bounds, rects, strip, size)
    for chunk, (x0, y0, x1, y1) in enumerate(bounds):
        owner = result.owner[chunk]
        on_screen = x1 > x0 and y1 > y0
        assert (owner == OFF_SCREEN) == (not on_screen)
        drawn_by = [t for t, draws in enumerate(result.draws) if chunk in draws]
        if owner >= 0:
            assert drawn_by == [owner]
        elif owner == SHARED:
            assert len(drawn_by) >= 1
        if not on_screen:
            assert drawn_by == []
            continue
        # pixels whose centre the bound covers (grown by half a pixel of rounding slack)
        xs = np.arange(max(int(np.floor(x0 - 0.5)), 0), min(int(np.ceil(x1 + 0.5)), size[0]))
        ys = np.arange(max(int(np.floor(y0 - 0.5)), 0), min(int(np.ceil(y1 + 0.5)), size[1]))
        for x in xs[[0, -1]] if xs.size else []:
            for y in ys[[0, -1]] if ys.size else []:
                holders = [t for t in drawn_by if result.readback[t].x <= x < result.readback[t].x1
                           and result.readback[t].y <= y < result.readback[t].y1]
                assert holders, (chunk, x, y)
                # and the pixel's own tile draws it whenever the chunk is shared
                if owner == SHARED:
                    home = next(t for t, r in enumerate(rects) if r.x <= x < r.x1 and r.y <= y < r.y1)
                    assert home in drawn_by


@settings(max_examples=60, deadline=None)
@given(tiles=st.integers(1, 24), strip=st.sampled_from([0, 1, 8, 40]), width=st.integers(16, 400),
       height=st.integers(16, 300))
def test_a_tile_core_is_reached_by_no_other_read_back_rect(tiles, strip, width, height):
    size = (width, height)
    rects = equal_strip_partition(tiles, size)
    for index, tile in enumerate(rects):
        core = exclusive_rect(tile, strip, size)
        if core is None:
            assert min(tile.w, tile.h) <= 2 * strip
            continue
        assert tile.x <= core.x and core.x1 <= tile.x1 and tile.y <= core.y and core.y1 <= tile.y1
        for other, rect in enumerate(rects):
            if other != index:
                assert readback_rect(rect, strip, size).intersection_area(core) == 0


def test_a_tile_core_keeps_the_frame_edges():
    assert exclusive_rect(TILES[0], 8, SIZE) == Rect(0, 0, 112, 100)
    assert exclusive_rect(TILES[1], 8, SIZE) == Rect(128, 0, 72, 100)
    assert exclusive_rect(Rect(50, 30, 20, 20), 8, SIZE) == Rect(58, 38, 4, 4)
    assert exclusive_rect(Rect(50, 30, 16, 20), 8, SIZE) is None
