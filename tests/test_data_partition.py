"""The sort-last data partition as pure functions: shares sized by node weight in triangles,
spatially coherent (boxes that barely overlap), deterministic; the read-back rect a share projects
to."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tessera.decomposition.data_partition import covering_rect, split_chunks
from tessera.geometry import Rect


def grid_chunks(side: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """side³ unit-cube chunks on a grid (C, 2, 3) with random triangle counts 1…192 (C,)."""
    cells = np.stack(np.meshgrid(*[np.arange(side)] * 3, indexing="ij"), axis=-1).reshape(-1, 3).astype(np.float64)
    return np.stack([cells, cells + 1.0], axis=1), rng.integers(1, 193, cells.shape[0])


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), weights=st.lists(st.floats(0.25, 4.0), min_size=1, max_size=7))
def test_shares_hold_triangles_in_proportion_to_the_weights(seed, weights):
    boxes, triangles = grid_chunks(8, np.random.default_rng(seed))
    share = split_chunks(boxes, triangles, weights)
    assert share.shape == triangles.shape and set(np.unique(share)) <= set(range(len(weights)))
    held = np.bincount(share, weights=triangles, minlength=len(weights))
    target = np.asarray(weights) / sum(weights) * triangles.sum()
    levels = int(np.ceil(np.log2(len(weights)))) if len(weights) > 1 else 0
    assert np.all(np.abs(held - target) <= levels * triangles.max())


def test_shares_are_spatially_coherent():
    boxes, triangles = grid_chunks(8, np.random.default_rng(1))
    share = split_chunks(boxes, triangles, [1, 1, 1, 1])
    volumes = []
    for node in range(4):
        mine = boxes[share == node]
        extent = mine[:, 1].max(axis=0) - mine[:, 0].min(axis=0)
        volumes.append(float(np.prod(extent)))
    # four k-d cells of an 8³ cube: their boxes add up to the cube, give or take one layer of cells
    assert sum(volumes) <= 8 ** 3 * 1.3


def test_one_node_holds_everything_and_weights_move_the_cut():
    boxes, triangles = grid_chunks(4, np.random.default_rng(2))
    assert (split_chunks(boxes, triangles, [3.0]) == 0).all()
    fast_first = np.bincount(split_chunks(boxes, triangles, [3.0, 1.0]), weights=triangles)
    assert fast_first[0] == pytest.approx(0.75 * triangles.sum(), abs=int(triangles.max()))


def test_the_partition_is_deterministic_and_ignores_input_types():
    boxes, triangles = grid_chunks(5, np.random.default_rng(3))
    first = split_chunks(boxes.astype(np.float32), triangles, [1, 2, 1])
    np.testing.assert_array_equal(first, split_chunks(boxes, triangles.tolist(), (1.0, 2.0, 1.0)))


def test_fewer_chunks_than_nodes_leaves_shares_empty():
    boxes, triangles = grid_chunks(1, np.random.default_rng(4))
    share = split_chunks(boxes, triangles, [1, 1, 1])
    assert share.shape == (1,)
    assert split_chunks(np.zeros((0, 2, 3)), np.zeros(0), [1, 1]).shape == (0,)


@pytest.mark.parametrize("weights", [[], [1, 0], [1, -1], [1, float("nan")]])
def test_bad_weights_are_refused(weights):
    boxes, triangles = grid_chunks(2, np.random.default_rng(5))
    with pytest.raises(ValueError, match="weights"):
        split_chunks(boxes, triangles, weights)


def test_covering_rect_holds_every_bound_with_a_margin_and_ignores_empty_ones():
    bounds = np.array([[10.2, 20.5, 30.0, 40.9], [0, 0, 0, 0], [50, 5, 50, 9], [25, 35, 60.5, 41]])
    assert covering_rect(bounds, (100, 80)) == Rect(9, 19, 53, 23)
    assert covering_rect(bounds, (100, 80), margin_px=0.0) == Rect(10, 20, 51, 21)
    assert covering_rect(np.array([[90, 70, 100, 80.0]]), (100, 80)) == Rect(89, 69, 11, 11)
    assert covering_rect(np.zeros((3, 4)), (100, 80)) is None
    assert covering_rect(np.zeros((0, 4)), (100, 80)) is None
