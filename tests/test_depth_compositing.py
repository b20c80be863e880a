"""The depth compositor and the active-pixel codec without GL (seed 000 §4.4): nearest depth wins,
ties go to the lower slot whatever the arrival order, background painted once where nothing drew,
empty layers and strips, integer depth refused or converted explicitly, lossless round trips."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tessera.compositing.depth_merge import merge_by_depth
from tessera.compositing.layers import FAR, DepthLayer, background_pixel, depth_from_integer, split_layer
from tessera.geometry import Rect
from tessera.wire.active_pixels import DepthCodecError, decode_active, encode_active

BACKGROUND = np.array([28, 31, 38], np.uint8)


def layer(rect: Rect, depth: float | np.ndarray, color: tuple[int, int, int], slot: int) -> DepthLayer:
    """A layer over ``rect`` of one colour at ``depth`` (a number, or an (h, w) array)."""
    depths = np.broadcast_to(np.asarray(depth, np.float32), (rect.h, rect.w)).copy()
    return DepthLayer(rect, np.full((rect.h, rect.w, 3), color, np.uint8), depths, slot)


def random_layer(rng: np.random.Generator, rect: Rect, slot: int, empty_share: float = 0.4) -> DepthLayer:
    """Random colours; depths on a coarse grid (so ties happen), ``empty_share`` of pixels far."""
    shape = (rect.h, rect.w)
    depth = (rng.integers(0, 8, shape) / 8.0).astype(np.float32)
    depth[rng.random(shape) < empty_share] = FAR
    return DepthLayer(rect, rng.integers(0, 256, (*shape, 3), dtype=np.uint8), depth, slot)


def reference_composite(layers: list[DepthLayer], size: tuple[int, int], background: np.ndarray) -> np.ndarray:
    """Per-pixel loop: the smallest (depth, slot) among layers that drew the pixel."""
    width, height = size
    frame = np.empty((height, width, 3), np.uint8)
    for y, x in itertools.product(range(height), range(width)):
        best = None
        for item in layers:
            r = item.rect
            if r.x <= x < r.x1 and r.y <= y < r.y1:
                d = float(item.depth[y - r.y, x - r.x])
                if d < 1.0 and (best is None or (d, item.slot) < best[:2]):
                    best = (d, item.slot, item.color[y - r.y, x - r.x])
        frame[y, x] = background if best is None else best[2]
    return frame


# ------------------------------------------------------------------------------------------ merge


def test_nearer_layer_wins_wherever_it_drew():
    near = layer(Rect(0, 0, 4, 2), 0.25, (255, 0, 0), slot=1)
    far = layer(Rect(2, 0, 4, 2), 0.75, (0, 255, 0), slot=0)
    frame = merge_by_depth([far, near], (6, 2), BACKGROUND)
    assert (frame[:, :4] == (255, 0, 0)).all()
    assert (frame[:, 4:] == (0, 255, 0)).all()


def test_ties_go_to_the_lower_slot_in_any_arrival_order():
    layers = [layer(Rect(0, 0, 3, 3), 0.5, (slot * 40, 0, 0), slot) for slot in (3, 1, 2)]
    for order in itertools.permutations(layers):
        frame = merge_by_depth(order, (3, 3), BACKGROUND)
        assert (frame == (40, 0, 0)).all()


def test_background_is_painted_once_where_no_layer_drew():
    # the layers' own colour where their depth is far is never used
    stray = layer(Rect(0, 0, 4, 4), FAR, (200, 200, 200), slot=0)
    dot_depth = np.full((4, 4), FAR, np.float32)
    dot_depth[1, 2] = 0.3
    dot = DepthLayer(Rect(0, 0, 4, 4), np.full((4, 4, 3), 9, np.uint8), dot_depth, 1)
    frame = merge_by_depth([stray, dot], (4, 4), BACKGROUND)
    expected = np.broadcast_to(BACKGROUND, (4, 4, 3)).copy()
    expected[1, 2] = 9
    np.testing.assert_array_equal(frame, expected)


def test_no_layers_and_empty_strips_give_the_background():
    assert (merge_by_depth([], (5, 3), BACKGROUND) == BACKGROUND).all()
    empty = layer(Rect(1, 1, 3, 2), FAR, (1, 2, 3), slot=0)
    zero_sized = DepthLayer(Rect(2, 2, 0, 0), np.zeros((0, 0, 3), np.uint8), np.zeros((0, 0), np.float32), 1)
    assert (merge_by_depth([empty, zero_sized], (5, 3), BACKGROUND) == BACKGROUND).all()


def test_depth_zero_is_drawn_and_far_ties_are_not():
    # a fragment on the near plane (depth 0) counts; two far pixels are not a tie between drawn pixels
    high = layer(Rect(0, 0, 2, 1), np.array([[0.0, FAR]]), (7, 7, 7), slot=5)
    low = layer(Rect(0, 0, 2, 1), np.array([[0.5, FAR]]), (8, 8, 8), slot=0)
    assert merge_by_depth([high, low], (2, 1), BACKGROUND).tolist() == [[[7, 7, 7], BACKGROUND.tolist()]]


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), count=st.integers(1, 5))
def test_merge_matches_a_per_pixel_reference(seed, count):
    rng = np.random.default_rng(seed)
    size = (9, 7)
    layers = []
    for slot in rng.permutation(count):
        x0, x1 = sorted(rng.integers(0, size[0] + 1, 2))
        y0, y1 = sorted(rng.integers(0, size[1] + 1, 2))
        layers.append(random_layer(rng, Rect(int(x0), int(y0), int(x1 - x0), int(y1 - y0)), int(slot)))
    np.testing.assert_array_equal(merge_by_depth(layers, size, BACKGROUND),
                                  reference_composite(layers, size, BACKGROUND))


def test_layer_outside_the_frame_or_slot_reused_is_refused():
    with pytest.raises(ValueError, match="outside"):
        merge_by_depth([layer(Rect(2, 2, 3, 1), 0.5, (0, 0, 0), slot=0)], (4, 4), BACKGROUND)
    twins = [layer(Rect(0, 0, 2, 2), 0.5, (0, 0, 0), slot=0), layer(Rect(1, 1, 1, 1), 0.5, (0, 0, 0), slot=0)]
    with pytest.raises(ValueError, match="own slot"):
        merge_by_depth(twins, (4, 4), BACKGROUND)
    with pytest.raises(ValueError, match="slot"):
        layer(Rect(0, 0, 1, 1), 0.5, (0, 0, 0), slot=-1)


# ----------------------------------------------------------------------------- depth formats


@pytest.mark.parametrize("dtype", [np.uint16, np.uint32, np.int32, np.float64, np.float16])
def test_depth_that_is_not_float32_is_refused(dtype):
    with pytest.raises(TypeError, match="float32"):
        DepthLayer(Rect(0, 0, 2, 2), np.zeros((2, 2, 3), np.uint8), np.zeros((2, 2), dtype), 0)


@pytest.mark.parametrize("bad", [np.nan, -0.25, 1.5])
def test_depth_outside_unit_range_is_refused(bad):
    depth = np.full((2, 2), 0.5, np.float32)
    depth[1, 1] = bad
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        DepthLayer(Rect(0, 0, 2, 2), np.zeros((2, 2, 3), np.uint8), depth, 0)


def test_wrong_shapes_are_refused():
    with pytest.raises(ValueError, match="needs depth"):
        DepthLayer(Rect(0, 0, 3, 2), np.zeros((2, 3, 3), np.uint8), np.zeros((3, 2), np.float32), 0)
    with pytest.raises(TypeError, match="uint8"):
        DepthLayer(Rect(0, 0, 3, 2), np.zeros((2, 3, 3), np.float32), np.zeros((2, 3), np.float32), 0)


def test_integer_depth_is_converted_explicitly_with_clear_value_far():
    values = np.array([[0, 1 << 23], [(1 << 24) - 2, (1 << 24) - 1]], np.uint32)
    depth = depth_from_integer(values, 24)
    assert depth.dtype == np.float32
    assert depth[0, 0] == 0.0 and depth[1, 1] == FAR and depth[1, 0] < FAR
    assert abs(float(depth[0, 1]) - 0.5) < 1e-6
    assert depth_from_integer(np.array([65535], np.uint16), 16)[0] == FAR
    with pytest.raises(ValueError, match="16-bit"):
        depth_from_integer(np.array([70000], np.uint32), 16)
    with pytest.raises(TypeError, match="integer"):
        depth_from_integer(np.array([0.5], np.float32), 24)


def test_background_pixel_rounds_as_an_8_bit_buffer():
    assert background_pixel((0.11, 0.12, 0.15)).tolist() == [28, 31, 38]
    assert background_pixel((0.0, 1.0, 0.5)).tolist() == [0, 255, 128]
    with pytest.raises(ValueError):
        background_pixel((0.0, 1.2, 0.0))


# ------------------------------------------------------------------------------------------ codec


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), width=st.integers(0, 23), height=st.integers(0, 17),
       empty_share=st.sampled_from([0.0, 0.3, 0.9, 1.0]))
def test_active_pixel_round_trip_is_lossless(seed, width, height, empty_share):
    rng = np.random.default_rng(seed)
    item = random_layer(rng, Rect(0, 0, width, height), 0, empty_share)
    depth = item.depth.copy()
    live = depth < FAR
    depth[live] = rng.random(int(live.sum()), dtype=np.float32)   # arbitrary float32 bits in [0, 1)
    back_depth, back_color = decode_active(encode_active(depth, item.color))
    assert back_depth.dtype == np.float32
    np.testing.assert_array_equal(back_depth.view(np.uint32), depth.view(np.uint32))
    np.testing.assert_array_equal(back_color[live], item.color[live])
    assert (back_color[~live] == 0).all()


def test_encoding_carries_only_active_pixels():
    depth = np.full((10, 20), FAR, np.float32)
    depth[3, 4:9] = 0.5
    depth[7, 0] = 0.25
    data = encode_active(depth, np.zeros((10, 20, 3), np.uint8))
    # header 8, three run pairs (gap, active) + the tail pair, 6 active pixels × (4 + 3) bytes
    assert len(data) == 8 + 3 * 8 + 6 * 7
    all_far = encode_active(np.full((720, 1280), FAR, np.float32), np.zeros((720, 1280, 3), np.uint8))
    assert len(all_far) == 8 + 8


@pytest.mark.parametrize("mutate", [
    lambda d: d[:5],                                  # no header
    lambda d: d[:-1],                                 # a colour byte short
    lambda d: d + b"\0",                              # a byte too many
    lambda d: d[:4] + (999).to_bytes(4, "little") + d[8:],   # run pairs do not fit
    lambda d: d[:8] + (6).to_bytes(4, "little") + d[12:],    # runs do not cover the layer
])
def test_malformed_bytes_are_refused(mutate):
    depth = np.full((4, 4), FAR, np.float32)
    depth[1:3, 1:3] = 0.5
    data = encode_active(depth, np.zeros((4, 4, 3), np.uint8))
    with pytest.raises(DepthCodecError):
        decode_active(mutate(data))


def test_active_depth_of_one_or_nan_is_refused_on_decode():
    depth = np.full((2, 2), FAR, np.float32)
    depth[0, 0] = 0.5
    data = bytearray(encode_active(depth, np.zeros((2, 2, 3), np.uint8)))
    offset = len(data) - 7
    for bad in (1.0, float("nan")):
        data[offset:offset + 4] = np.float32(bad).tobytes()
        with pytest.raises(DepthCodecError, match="depth"):
            decode_active(bytes(data))


def test_layers_and_codec_take_arrays_that_are_not_contiguous():
    rng = np.random.default_rng(7)
    item = random_layer(rng, Rect(0, 0, 6, 5), 0)
    flipped = DepthLayer(item.rect, item.color[::-1], item.depth[::-1], 0)
    expected = reference_composite([flipped], (6, 5), BACKGROUND)
    np.testing.assert_array_equal(merge_by_depth([flipped], (6, 5), BACKGROUND), expected)
    depth, color = decode_active(encode_active(flipped.depth, flipped.color))
    np.testing.assert_array_equal(depth, flipped.depth)
    live = depth < FAR
    np.testing.assert_array_equal(color[live], flipped.color[live])


def test_a_split_layer_composes_as_the_whole_and_only_its_strips_carry_depth():
    rng = np.random.default_rng(11)
    whole = random_layer(rng, Rect(3, 2, 8, 6), 4, empty_share=0.2)
    whole.color[whole.depth >= FAR] = BACKGROUND     # as GL clears it: the core goes as drawn
    other = random_layer(rng, Rect(0, 0, 6, 5), 1)
    core = Rect(5, 3, 4, 3)
    strips, core_color = split_layer(whole, core)
    assert [piece.rect for piece in strips] == [Rect(3, 2, 8, 1), Rect(3, 6, 8, 2), Rect(3, 3, 2, 3),
                                                 Rect(9, 3, 2, 3)]
    assert all(piece.slot == 4 for piece in strips) and sum(p.rect.area for p in strips) + core.area == 48
    assert core_color is not None
    np.testing.assert_array_equal(core_color, whole.color[1:4, 2:6])
    # the core is exclusive: nothing else reaches it here, so merging the pieces and pasting it is exact
    reference = reference_composite([whole], (12, 9), BACKGROUND)
    np.testing.assert_array_equal(merge_by_depth(strips, (12, 9), BACKGROUND, [(core, core_color)]), reference)
    assert split_layer(whole, None) == ([whole], None)
    with pytest.raises(ValueError, match="inside"):
        split_layer(whole, Rect(9, 3, 4, 1))
    # pieces of one slot may not overlap; other slots may
    np.testing.assert_array_equal(merge_by_depth([*strips, other], (12, 9), BACKGROUND),
                                  merge_by_depth([*strips, other][::-1], (12, 9), BACKGROUND))
    with pytest.raises(ValueError, match="overlap"):
        merge_by_depth([*strips, DepthLayer(Rect(0, 0, 4, 3), other.color[:3, :4], other.depth[:3, :4], 4)], (12, 9),
                  BACKGROUND)
    with pytest.raises(ValueError, match="exclusive"):
        merge_by_depth([], (12, 9), BACKGROUND, [(Rect(10, 0, 4, 1), np.zeros((1, 4, 3), np.uint8))])
