"""Tile codecs: exact RAW/PNG round trips, close JPEG, and clear errors for bad input."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from bench.images import psnr
from tessera.wire.codec import Codec, CodecError, decode, encode, encode_png

images = st.tuples(st.integers(1, 40), st.integers(1, 40)).flatmap(
    lambda hw: arrays(np.uint8, (hw[0], hw[1], 3)))


def gradient(width: int = 96, height: int = 64) -> np.ndarray:
    """A smooth (height, width, 3) uint8 test image."""
    x, y = np.meshgrid(np.linspace(0.0, 1.0, width), np.linspace(0.0, 1.0, height))
    return (np.stack([x, y, (x + y) / 2.0], axis=2) * 255.0).round().astype(np.uint8)


@settings(max_examples=40, deadline=None)
@given(pixels=images, codec=st.sampled_from([Codec.RAW, Codec.PNG]))
def test_lossless_codecs_round_trip_exactly(pixels, codec):
    height, width, _ = pixels.shape
    decoded = decode(encode(pixels, codec), codec, width, height)
    assert decoded.shape == (height, width, 3) and decoded.dtype == np.uint8
    np.testing.assert_array_equal(decoded, pixels)


@pytest.mark.parametrize("codec", [Codec.RAW, Codec.PNG, Codec.JPEG])
def test_non_contiguous_views_encode_like_copies(codec):
    image = gradient(80, 60)
    view = image[5:45:2, ::3]
    assert not view.flags.c_contiguous
    assert encode(view, codec) == encode(np.ascontiguousarray(view), codec)


@pytest.mark.parametrize(("quality", "min_psnr"), [(85, 35.0), (95, 40.0)])
def test_jpeg_is_close_on_a_smooth_gradient(quality, min_psnr):
    image = gradient()
    data = encode(image, Codec.JPEG, jpeg_quality=quality)
    assert data[:2] == b"\xff\xd8"
    decoded = decode(data, Codec.JPEG, 96, 64)
    assert decoded.shape == image.shape and decoded.dtype == np.uint8
    assert psnr(decoded, image) > min_psnr


def test_png_is_png_and_encode_png_is_lossless():
    image = gradient(33, 17)
    data = encode_png(image)
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    np.testing.assert_array_equal(decode(data, Codec.PNG, 33, 17), image)


@pytest.mark.parametrize("codec", list(Codec))
@pytest.mark.parametrize(("width", "height"), [(33, 17), (32, 16), (1, 1)])
def test_decode_rejects_the_wrong_size(codec, width, height):
    data = encode(gradient(32, 17), codec)
    with pytest.raises(CodecError, match="expected"):
        decode(data, codec, width, height)


@pytest.mark.parametrize("codec", [Codec.PNG, Codec.JPEG])
@pytest.mark.parametrize("data", [b"", b"not an image at all", b"\x89PNG\r\n\x1a\n" + b"\0" * 40,
                                  b"\xff\xd8\xff" + b"\0" * 40])
def test_decode_rejects_garbage(codec, data):
    with pytest.raises(CodecError, match=codec.name):
        decode(data, codec, 4, 4)


@pytest.mark.parametrize("codec", [Codec.PNG, Codec.JPEG])
def test_decode_rejects_a_truncated_image(codec):
    data = encode(gradient(64, 64), codec)
    with pytest.raises(CodecError):
        decode(data[: len(data) // 2], codec, 64, 64)


@pytest.mark.parametrize("codec", list(Codec))
@pytest.mark.parametrize("pixels", [
    np.zeros((4, 4, 3), dtype=np.float32), np.zeros((4, 4, 3), dtype=np.uint16), np.zeros((4, 4), dtype=np.uint8),
    np.zeros((4, 4, 4), dtype=np.uint8), np.zeros((4, 4, 1), dtype=np.uint8), np.zeros((2, 4, 4, 3), dtype=np.uint8),
], ids=["float32", "uint16", "2d", "rgba", "one-channel", "4d"])
def test_encode_rejects_anything_but_hw3_uint8(codec, pixels):
    with pytest.raises(ValueError, match=r"\(h, w, 3\) uint8"):
        encode(pixels, codec)


@pytest.mark.parametrize(("name", "codec"), [("jpeg", Codec.JPEG), ("PNG", Codec.PNG), ("Raw", Codec.RAW)])
def test_codec_parse(name, codec):
    assert Codec.parse(name) is codec


@pytest.mark.parametrize("name", ["webp", "", "jpg", "1"])
def test_codec_parse_lists_the_choices(name):
    with pytest.raises(ValueError, match=r"choose one of \['raw', 'jpeg', 'png'\]"):
        Codec.parse(name)


def test_codec_wire_values_are_fixed():
    assert [(c.name, int(c)) for c in Codec] == [("RAW", 0), ("JPEG", 1), ("PNG", 2)]
