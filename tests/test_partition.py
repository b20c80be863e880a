"""Partition math and the static balancer: strips→tiles topology, integer splits, exact cover."""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from tessera.balancers import BALANCERS, create_balancer
from tessera.balancers.base import (
    BalanceInput,
    Balancer,
    Partition,
    Tile,
    TileTiming,
    busy_by_node,
    imbalance,
)
from tessera.balancers.partition import (
    check_exact_cover,
    clamp_edges,
    equal_strip_partition,
    split_length,
    strip_counts,
    strips_to_rects,
)
from tessera.geometry import Rect

SCREENS = [(1280, 720), (1920, 1080), (1024, 1024), (720, 1280), (3840, 1080), (800, 600), (16, 16)]
screen_side = st.integers(16, 1500)


# -------------------------------------------------------------------------------------- strip counts


@pytest.mark.parametrize("size", SCREENS)
def test_strip_counts_sum_to_n_and_differ_by_at_most_one(size):
    for n in range(1, 65):
        counts = strip_counts(n, size)
        assert sum(counts) == n
        assert max(counts) - min(counts) <= 1
        assert counts == sorted(counts, reverse=True), "the first strips hold the extra tile"


@pytest.mark.parametrize("size", [(1280, 720), (1920, 1080)])
def test_equal_tiles_on_16_by_9_are_roughly_square(size):
    for n in range(4, 65):
        for rect in equal_strip_partition(n, size):
            assert 1 / 2.5 <= rect.w / rect.h <= 2.5, f"{n} tiles: {rect} is far from square"


def test_strip_counts_follow_the_screen_shape():
    assert strip_counts(4, (1000, 1000)) == [2, 2]
    assert strip_counts(3, (3000, 100)) == [3]
    assert strip_counts(3, (100, 3000)) == [1, 1, 1]
    assert strip_counts(5, (1000, 1000)) == [3, 2]


def test_strip_counts_needs_a_tile():
    with pytest.raises(ValueError, match="at least one tile"):
        strip_counts(0, (640, 480))


# -------------------------------------------------------------------------------------- split_length


@settings(max_examples=150, deadline=None)
@given(total=st.integers(1, 5000), weights=st.lists(st.floats(0.0, 100.0), min_size=1, max_size=64),
       minimum=st.integers(0, 40))
def test_split_length_sums_to_total_and_respects_the_minimum(total, weights, minimum):
    assume(len(weights) * minimum <= total)
    lengths = split_length(total, weights, minimum)
    assert len(lengths) == len(weights)
    assert sum(lengths) == total
    assert min(lengths) >= minimum


@settings(max_examples=150, deadline=None)
@given(total=st.integers(1, 5000), weights=st.lists(st.floats(0.01, 100.0), min_size=1, max_size=64),
       minimum=st.integers(0, 8))
def test_split_length_is_proportional_within_one_pixel(total, weights, minimum):
    exact = np.asarray(weights) / sum(weights) * total
    assume(exact.min() >= minimum + 1)
    lengths = split_length(total, weights, minimum)
    assert np.abs(np.asarray(lengths) - exact).max() <= 1.0
    assert np.abs(np.cumsum(lengths) - np.cumsum(exact)).max() <= 0.5 + 1e-9, "every edge within half a pixel"


@pytest.mark.parametrize("weights", [[0.0, 0.0, 0.0], [-1.0, -2.0, -3.0], [float("nan"), 1.0, 1.0],
                                     [float("inf"), 1.0, 1.0]])
def test_split_length_falls_back_to_equal_parts_for_unusable_weights(weights):
    assert split_length(30, weights) == [10, 10, 10]


def test_split_length_treats_negative_weights_as_zero():
    assert split_length(100, [-5.0, 1.0, 3.0], minimum=0) == [0, 25, 75]


def test_split_length_refuses_an_impossible_minimum():
    with pytest.raises(ValueError, match="cannot split 10 px into 3 parts of at least 4 px"):
        split_length(10, [1, 1, 1], minimum=4)


@pytest.mark.parametrize(("edges", "total", "minimum", "lengths"), [
    ([0, 0, 0, 10], 10, 2, [2, 2, 6]),
    ([0, 10, 10, 10], 10, 2, [6, 2, 2]),
    ([0, 8, 3, 10], 10, 1, [8, 1, 1]),
    ([5, 3, 7, 99], 10, 1, [3, 4, 3]),
    ([0, 4, 6, 10], 10, 1, [4, 2, 4]),
])
def test_clamp_edges(edges, total, minimum, lengths):
    assert clamp_edges(edges, total, minimum) == lengths


@settings(max_examples=100, deadline=None)
@given(total=st.integers(1, 500), inner=st.lists(st.integers(-100, 600), max_size=30), minimum=st.integers(0, 10))
def test_clamp_edges_always_gives_valid_lengths(total, inner, minimum):
    assume((len(inner) + 1) * minimum <= total)
    lengths = clamp_edges([0, *inner, total], total, minimum)
    assert len(lengths) == len(inner) + 1
    assert sum(lengths) == total and min(lengths) >= minimum
    given_lengths = [b - a for a, b in zip([0, *inner], [*inner, total], strict=True)]
    if min(given_lengths) >= minimum:
        assert lengths == given_lengths, "valid edges are left alone"


def test_strips_to_rects_is_row_major():
    assert strips_to_rects((10, 6), [4, 2], [[3, 7], [10]]) == [Rect(0, 0, 3, 4), Rect(3, 0, 7, 4), Rect(0, 4, 10, 2)]


# ------------------------------------------------------------------------------ equal strip partition


@settings(max_examples=120, deadline=None)
@given(n=st.integers(1, 64), width=screen_side, height=screen_side)
def test_equal_strip_partition_covers_exactly_with_equal_areas(n, width, height):
    rects = equal_strip_partition(n, (width, height))
    assert len(rects) == n
    check_exact_cover(rects, (width, height))
    counts = strip_counts(n, (width, height))
    strip_tops = sorted({r.y for r in rects})
    assert [sum(r.y == top for r in rects) for top in strip_tops] == counts
    for rect in rects:
        tiles_in_strip = counts[strip_tops.index(rect.y)]
        ideal_w, ideal_h = width / tiles_in_strip, height * tiles_in_strip / n
        assert abs(rect.w - ideal_w) < 1.0 and abs(rect.h - ideal_h) < 1.0
        assert abs(rect.area - width * height / n) < ideal_w + ideal_h + 1.0


@settings(max_examples=150, deadline=None)
@given(n=st.integers(1, 64), width=st.integers(1, 40), height=st.integers(1, 40))
def test_equal_strip_partition_on_tiny_screens_covers_or_refuses(n, width, height):
    try:
        rects = equal_strip_partition(n, (width, height))
    except ValueError:
        assert n > min(width, height), f"{n} tiles fit one per row and column on {width}x{height}"
        return
    assert n <= width * height
    assert len(rects) == n
    check_exact_cover(rects, (width, height))


@pytest.mark.parametrize(("n", "size"), [(1, (1, 1)), (6, (3, 2)), (6, (2, 3)), (64, (8, 8)), (64, (16, 16)),
                                         (5, (5, 1)), (5, (1, 5))])
def test_equal_strip_partition_down_to_one_pixel_tiles(n, size):
    check_exact_cover(equal_strip_partition(n, size), size)


@pytest.mark.parametrize("n", [2, 5, 64])
def test_equal_strip_partition_refuses_more_tiles_than_pixels(n):
    with pytest.raises(ValueError):
        equal_strip_partition(n, (1, 1))


# ------------------------------------------------------------------------------------ exact cover


@pytest.mark.parametrize(("rects", "fragment"), [
    ([Rect(0, 0, 6, 4), Rect(5, 0, 5, 4)], "exactly once"),
    ([Rect(0, 0, 4, 4), Rect(5, 0, 5, 4)], "exactly once"),
    ([Rect(0, 0, 10, 3)], "exactly once"),
    ([Rect(0, 0, 10, 4), Rect(0, 0, 10, 4)], "exactly once"),
    ([Rect(0, 0, 5, 4), Rect(5, 0, 6, 4)], "outside"),
    ([Rect(-1, 0, 6, 4), Rect(5, 0, 5, 4)], "outside"),
    ([Rect(0, 0, 10, 5)], "outside"),
    ([Rect(0, 0, 5, 4), Rect(5, 0, 0, 4), Rect(5, 0, 5, 4)], "empty"),
    ([Rect(0, 0, 10, 0), Rect(0, 0, 10, 4)], "empty"),
    ([Rect(0, 0, 5.0, 4), Rect(5, 0, 5, 4)], "non-integer"),
    ([], "exactly once"),
])
def test_check_exact_cover_rejects(rects, fragment):
    with pytest.raises(ValueError, match=fragment):
        check_exact_cover(rects, (10, 4))


def test_check_exact_cover_accepts_an_irregular_cover():
    check_exact_cover([Rect(0, 0, 3, 4), Rect(3, 0, 7, 1), Rect(3, 1, 2, 3), Rect(5, 1, 5, 3)], (10, 4))


# ---------------------------------------------------------------------------------- static balancer


@settings(max_examples=80, deadline=None)
@given(node_ids=st.lists(st.integers(0, 10_000), min_size=1, max_size=64, unique=True),
       width=screen_side, height=screen_side, data=st.data())
def test_static_partition_gives_each_node_one_tile_of_an_exact_cover(node_ids, width, height, data):
    size = (width, height)
    partition = create_balancer("static").partition(BalanceInput(size, tuple(node_ids)))
    assert not partition.pull
    check_exact_cover(partition.rects, size)
    assert sorted(t.node_id for t in partition.tiles) == sorted(node_ids)
    shuffled = tuple(data.draw(st.permutations(node_ids)))
    timings = tuple(TileTiming(t.rect, t.node_id, render_ms=float(i)) for i, t in enumerate(partition.tiles))
    again = create_balancer("static").partition(
        BalanceInput(size, shuffled, previous=partition, timings=timings, weights={node_ids[0]: 5.0}, elapsed_ms=9.0))
    assert again == partition, "static ignores measurements and node order"


def test_static_respects_min_tile_px_where_it_fits():
    partition = create_balancer("static", {"min_tile_px": 40}).partition(BalanceInput((400, 300), (1, 2, 3)))
    assert min(min(r.w, r.h) for r in partition.rects) >= 40


def test_static_params_are_merged_with_defaults():
    assert create_balancer("static").params == {"min_tile_px": 16}
    assert create_balancer("static", {"min_tile_px": 4}).params == {"min_tile_px": 4}


def test_unknown_parameter_is_named_with_the_accepted_ones():
    with pytest.raises(ValueError, match=r"no parameters \['speed'\].*min_tile_px"):
        create_balancer("static", {"speed": 2})


@pytest.mark.parametrize("value", ["many", None, [3], 0, -4, float("nan"), float("inf")])
def test_bad_parameter_values_raise_value_error(value):
    with pytest.raises(ValueError, match="min_tile_px"):
        create_balancer("static", {"min_tile_px": value})


@pytest.mark.parametrize("value", [2.5, True])
def test_parameter_values_are_not_silently_coerced(value):
    with pytest.raises(ValueError, match="min_tile_px"):
        create_balancer("static", {"min_tile_px": value})


class FlagBalancer(Balancer):
    name = "flag-test"
    defaults: ClassVar[Mapping[str, float | int | bool]] = {"adaptive": True}

    def partition(self, inputs: BalanceInput) -> Partition:
        raise NotImplementedError


@pytest.mark.parametrize("text", ["false", "0", "no"])
def test_boolean_parameters_do_not_read_strings_as_true(text):
    try:
        balancer = FlagBalancer(adaptive=text)
    except ValueError:
        return
    assert balancer.params["adaptive"] is False, f"{text!r} became {balancer.params['adaptive']!r}"


def test_unknown_balancer_lists_the_choices():
    with pytest.raises(ValueError, match="unknown balancer 'nope'") as excinfo:
        create_balancer("nope")
    assert BALANCERS and all(name in str(excinfo.value) for name in BALANCERS)


# ------------------------------------------------------------------------------ timings and balance


def test_busy_by_node_sums_every_phase_per_node():
    timings = (
        TileTiming(Rect(0, 0, 1, 1), 7, render_ms=10.0, readback_ms=1.0, encode_ms=2.0, send_ms=3.0),
        TileTiming(Rect(1, 0, 1, 1), 3, render_ms=4.0),
        TileTiming(Rect(2, 0, 1, 1), 7, render_ms=5.0, send_ms=0.5),
    )
    assert timings[0].busy_ms == 16.0
    assert busy_by_node(timings) == {7: 21.5, 3: 4.0}


@pytest.mark.parametrize(("busy", "expected"), [
    ({}, 1.0), ({1: 0.0, 2: 0.0}, 1.0), ({1: 10.0}, 1.0), ({1: 10.0, 2: 30.0}, 1.5),
    ({1: 10.0, 2: 10.0, 3: 40.0}, 2.0), ({1: 10.0, 2: 30.0, 3: float("nan")}, 1.5),
])
def test_imbalance_is_max_over_mean(busy, expected):
    assert imbalance(busy) == pytest.approx(expected)


def test_previous_matches_only_the_same_nodes_and_screen():
    tiles = (Tile(Rect(0, 0, 50, 100), 1), Tile(Rect(50, 0, 50, 100), 2))
    previous = Partition(tiles)
    assert BalanceInput((100, 100), (2, 1), previous=previous).previous_matches()
    assert not BalanceInput((100, 100), (1, 2, 3), previous=previous).previous_matches()
    assert not BalanceInput((200, 100), (1, 2), previous=previous).previous_matches()
    assert not BalanceInput((100, 100), (1, 2)).previous_matches()
    pulled = Partition(tuple(Tile(t.rect, None) for t in tiles), pull=True)
    assert BalanceInput((100, 100), (1, 2, 3), previous=pulled).previous_matches()


def test_check_exact_cover_rejects_an_overlap_plus_a_hole_of_equal_area():
    """Areas summing to the screen are not enough: the tiles overlap where a strip stays uncovered."""
    with pytest.raises(ValueError, match="exactly once"):
        check_exact_cover([Rect(0, 0, 6, 4), Rect(5, 0, 5, 4)], (11, 4))
    with pytest.raises(ValueError, match="exactly once"):
        check_exact_cover([Rect(0, 0, 6, 2), Rect(5, 0, 5, 2), Rect(0, 2, 9, 2)], (10, 4))
