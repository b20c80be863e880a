"""Video to the browser (issue 21), the pure parts: the TVID message, codec strings, the transport a
viewer gets, the link's rate control, and the encoder's YUV picture from tiles."""

from __future__ import annotations

import io
from fractions import Fraction

import av
import numpy as np
import pytest
from PIL import Image

from tessera.geometry import Rect
from tessera.video.feedback import KEYFRAME_BURST, MAX_MALFORMED, FeedbackGuard
from tessera.video.link_rate import CLEAN_WINDOWS, MIN_BITRATE, MIN_FPS, WINDOW_S, LinkRate, LinkReport
from tessera.video.transport import choose_transport
from tessera.video.yuv_frame import coded_size, compose_yuv420, decoded_planes, rgb_of_yuv420, tile_planes
from tessera.wire.codec import Codec, encode
from tessera.wire.protocol import ProtocolError, with_input_seq
from tessera.wire.stream_messages import StreamReport
from tessera.wire.video import VideoCodec, codec_string, is_video, pack_video, unpack_video


def test_video_message_round_trip_and_input_number() -> None:
    message = pack_video(7, (641, 361), VideoCodec.VP9, True, b"\x00\x01unit")
    assert is_video(message) and not is_video(b"TFRM" + message[4:])
    frame = unpack_video(with_input_seq(message, 42))
    assert (frame.frame_id, frame.size, frame.codec, frame.keyframe, frame.input_seq, frame.data) == \
        (7, (641, 361), VideoCodec.VP9, True, 42, b"\x00\x01unit")
    assert not unpack_video(pack_video(8, (16, 16), VideoCodec.H264, False, b"x")).keyframe


UNIT = pack_video(1, (2, 2), VideoCodec.H264, False, b"x")


@pytest.mark.parametrize("message, reason", [
    (b"TVID", "shorter than its header"),
    (b"XXXX" + pack_video(1, (2, 2), VideoCodec.H264, False, b"x")[4:], "bad video magic"),
    (pack_video(1, (2, 2), VideoCodec.H264, False, b""), "without an access unit"),
    (UNIT[:6] + b"\x09" + UNIT[7:], "unknown video codec 9"),
])
def test_malformed_video_messages_say_what_is_wrong(message: bytes, reason: str) -> None:
    with pytest.raises(ProtocolError, match=reason):
        unpack_video(message)


def test_codec_strings_name_the_smallest_level_that_holds_the_frames() -> None:
    assert codec_string(VideoCodec.H264, (640, 360), 30) == "avc1.4d401e"      # level 3.0
    assert codec_string(VideoCodec.H264, (1280, 720), 30) == "avc1.4d401f"     # 3.1
    assert codec_string(VideoCodec.H264, (1280, 720), 60) == "avc1.4d4020"     # 3.2
    assert codec_string(VideoCodec.H264, (1920, 1080), 60) == "avc1.4d402a"    # 4.2
    assert codec_string(VideoCodec.H264, (3840, 2160), 30) == "avc1.4d4033"    # 5.1
    assert codec_string(VideoCodec.VP9, (1280, 720), 30) == "vp09.00.31.08"
    assert codec_string(VideoCodec.VP9, (1920, 1080), 60) == "vp09.00.41.08"


@pytest.mark.parametrize("mode, offered, codec, reason", [
    ("auto", ["h264", "vp9"], VideoCodec.H264, None),
    ("auto", ["vp9", "h264"], VideoCodec.H264, "the coordinator sends h264 (--stream auto)"),
    ("auto", ["vp9"], VideoCodec.VP9, None),
    ("auto", ["av1"], None, "the viewer decodes av1, not h264 or vp9 (--stream auto)"),
    ("auto", [], None, "the viewer decodes no video (no WebCodecs)"),
    ("vp9", ["h264", "VP9"], VideoCodec.VP9, "the coordinator sends vp9 (--stream vp9)"),
    ("h264", ["vp9"], None, "the viewer decodes vp9, not h264 (--stream h264)"),
    ("tiles", ["h264"], None, "the coordinator sends tiles (--stream tiles)"),
])
def test_transport_follows_stream_mode_and_what_the_viewer_decodes(mode, offered, codec, reason) -> None:
    assert choose_transport(mode, offered) == (codec, reason)


def clean(delivered: float = 1e6) -> LinkReport:
    return LinkReport(delivered_bps=delivered, dropped=0, decode_queue=0.0, backlog=1)


def test_congestion_cuts_the_bitrate_then_the_frame_rate_and_clean_windows_restore_them() -> None:
    rate, now = LinkRate(4e6, 60.0), 0.0
    assert not rate.update([], now)                      # no viewer reported: nothing to follow
    assert rate.update([LinkReport(delivered_bps=1e6, dropped=2, decode_queue=0.0, backlog=0)], now)
    assert rate.bitrate == pytest.approx(0.7e6)          # 0.7 × what got through, not 0.7 × the cap
    assert not rate.update([LinkReport(delivered_bps=1e5, dropped=2, decode_queue=0.0, backlog=0)], now + 0.5)
    while rate.bitrate > MIN_BITRATE:
        now += WINDOW_S
        rate.update([LinkReport(delivered_bps=1e9, dropped=0, decode_queue=9.0, backlog=0)], now)
    assert rate.fps == 60.0
    now += WINDOW_S
    assert rate.update([LinkReport(delivered_bps=1e9, dropped=0, decode_queue=0.0, backlog=5)], now)
    assert rate.bitrate == MIN_BITRATE and rate.fps == pytest.approx(42.0)
    for _ in range(200):
        now += WINDOW_S
        rate.update([clean(), LinkReport(delivered_bps=0, dropped=1, decode_queue=0.0, backlog=0)], now)
    assert rate.fps == MIN_FPS                           # the worst link rules
    for _ in range(400):
        now += WINDOW_S
        rate.update([clean()], now)
    assert (rate.bitrate, rate.fps) == (4e6, 60.0)


def test_congestion_at_a_few_pictures_a_second_cuts_the_cap_to_what_a_picture_got_through() -> None:
    """The cap is a rate at the nominal frame rate: a stream of 2 pictures a second, 5 KB each
    (80 kbit/s), congested for a window, keeps 0.7 of those bits a picture (1.68 Mbit/s at 60 fps),
    not 0.7 x 80 kbit/s (the 200 kbit/s floor: 420 bytes a 720p picture, about 10 dB)."""
    rate = LinkRate(4.7e6, 60.0)
    rate.update([clean()], 0.0)
    for _ in range(2):
        rate.picture()
    assert rate.update([LinkReport(delivered_bps=80e3, dropped=1, decode_queue=0.0, backlog=0)], WINDOW_S)
    assert rate.bitrate == pytest.approx(0.7 * 80e3 * 60.0 / 2.0)
    for _ in range(60):                                  # at the nominal rate, what got through is the rate
        rate.picture()
    assert rate.update([LinkReport(delivered_bps=1e6, dropped=1, decode_queue=0.0, backlog=0)], 2 * WINDOW_S)
    assert rate.bitrate == pytest.approx(0.7e6)


def test_a_clean_link_raises_nothing_for_a_few_windows_and_a_new_size_keeps_a_lowered_cap() -> None:
    rate = LinkRate(4e6, 30.0)
    rate.update([LinkReport(delivered_bps=1e6, dropped=1, decode_queue=0.0, backlog=0)], 0.0)
    lowered = rate.bitrate
    for step in range(1, CLEAN_WINDOWS):
        assert not rate.update([clean()], step * WINDOW_S)
    assert rate.update([clean()], CLEAN_WINDOWS * WINDOW_S) and rate.bitrate == pytest.approx(lowered * 1.25)
    rate.set_ceiling(9e6)
    assert rate.bitrate == pytest.approx(lowered * 1.25)
    rate.set_ceiling(1e5)
    assert rate.bitrate == MIN_BITRATE
    fresh = LinkRate(4e6, 30.0)
    fresh.set_ceiling(9e6)
    assert fresh.bitrate == 9e6


def rgb_to_ycbcr(rgb: np.ndarray) -> np.ndarray:
    """Reference JFIF conversion, float."""
    r, g, b = (rgb[..., i].astype(np.float64) for i in range(3))
    return np.stack([0.299 * r + 0.587 * g + 0.114 * b,
                     128 - 0.168736 * r - 0.331264 * g + 0.5 * b,
                     128 + 0.5 * r - 0.418688 * g - 0.081312 * b], axis=-1)


def block_means(values: np.ndarray) -> np.ndarray:
    """(h, w) → (h/2, w/2): the mean of each 2×2 block (h and w even)."""
    return (values[0::2, 0::2] + values[1::2, 0::2] + values[0::2, 1::2] + values[1::2, 1::2]) / 4.0


def chroma_planes(planes: np.ndarray, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """The Cb and Cr planes (h/2, w/2) of a yuv420p picture of the coded ``size`` (w, h), float."""
    width, height = size
    flat = planes[height:].reshape(-1).astype(np.float64)
    quarter = (height // 2) * (width // 2)
    return flat[:quarter].reshape(height // 2, width // 2), flat[quarter:].reshape(height // 2, width // 2)


def ramp_tiles(rects: list[Rect], codecs: tuple[Codec, ...]) -> tuple[np.ndarray, np.ndarray]:
    """A 101x67 frame of colour ramps (h, w, 3) uint8 (odd: padded to 102x68) and its yuv420p
    picture from the tiles ``rects`` in ``codecs`` (JPEG at q95)."""
    width, height = 101, 67
    yy, xx = np.mgrid[0:height, 0:width]
    rgb = np.stack([(xx * 2) % 256, (yy * 3) % 256, ((xx + yy) * 2) % 256], axis=-1).astype(np.uint8)
    tiles = [(rect, codec, 0, encode(np.ascontiguousarray(rgb[rect.y:rect.y1, rect.x:rect.x1]), codec, 95))
             for rect, codec in zip(rects, codecs, strict=True)]
    return rgb, compose_yuv420((width, height), tiles)


def test_the_picture_from_jpeg_png_and_raw_tiles_is_the_frame_in_ycbcr_420() -> None:
    rgb, planes = ramp_tiles([Rect(0, 0, 50, 67), Rect(50, 0, 51, 30), Rect(50, 30, 51, 37)],
                             (Codec.JPEG, Codec.PNG, Codec.RAW))
    width, height = 101, 67
    coded_w, coded_h = coded_size((width, height))
    assert (coded_w, coded_h) == (102, 68) and planes.shape == (coded_h * 3 // 2, coded_w)
    expected = rgb_to_ycbcr(rgb)
    luma = planes[:coded_h].astype(np.float64)
    assert np.abs(luma[:67, 50:101] - expected[:, 50:, 0]).max() <= 1.0     # PNG and raw: exact but rounding
    assert np.abs(luma[:67, :50] - expected[:, :50, 0]).mean() < 2.0       # JPEG q95 (4:4:4): near
    assert np.array_equal(luma[:, 101], luma[:, 100]) and np.array_equal(luma[67], luma[66])
    cb, cr = chroma_planes(planes, (coded_w, coded_h))
    for plane, channel in ((cb, 1), (cr, 2)):           # PNG and raw: the mean of each 2×2 block
        assert np.abs(plane[:33, 25:50] - block_means(expected[:66, 50:100, channel])).max() <= 1.0


def test_a_frame_of_rgb_tiles_is_converted_whole_its_chroma_from_block_means() -> None:
    """Raw and PNG tiles only (local nodes' tiles of a video session): the frame is laid out and
    converted at once; luma within a level of the JFIF conversion, each chroma sample within a
    level of its 2×2 block's mean, the padding the last row and column."""
    rgb, planes = ramp_tiles([Rect(0, 0, 51, 67), Rect(51, 0, 50, 31), Rect(51, 31, 50, 36)],
                             (Codec.RAW, Codec.PNG, Codec.RAW))
    coded_w, coded_h = coded_size((101, 67))
    assert planes.shape == (coded_h * 3 // 2, coded_w)
    expected = rgb_to_ycbcr(rgb)
    luma = planes[:coded_h].astype(np.float64)
    assert np.abs(luma[:67, :101] - expected[..., 0]).max() <= 1.0
    assert np.array_equal(luma[:, 101], luma[:, 100]) and np.array_equal(luma[67], luma[66])
    cb, cr = chroma_planes(planes, (coded_w, coded_h))
    for plane, channel in ((cb, 1), (cr, 2)):
        assert np.abs(plane[:33, :50] - block_means(expected[:66, :100, channel])).max() <= 1.0


def test_jpeg_tiles_at_odd_columns_and_rows_put_their_chroma_on_the_frames_grid() -> None:
    width, height = 60, 60
    yy, xx = np.mgrid[0:height, 0:width]
    # steep ramps (2 levels of Cr a row, of Cb a column): a chroma sample a pixel off is 2 levels off
    rgb = np.stack([4 * yy, np.full_like(xx, 100), 4 * xx], axis=-1).astype(np.uint8)
    rects = [Rect(0, 0, 33, 27), Rect(33, 0, 27, 27), Rect(0, 27, 20, 33), Rect(20, 27, 40, 33)]
    tiles = []
    for rect in rects:
        buffer = io.BytesIO()   # JPEG 4:2:0 at a high quality: the ramps come back nearly exact
        Image.fromarray(np.ascontiguousarray(rgb[rect.y:rect.y1, rect.x:rect.x1])).save(
            buffer, "JPEG", quality=98, subsampling=2)
        tiles.append((rect, Codec.JPEG, 0, buffer.getvalue()))
    planes = compose_yuv420((width, height), tiles)
    expected = rgb_to_ycbcr(rgb)
    assert np.abs(planes[:height] - expected[..., 0]).mean() < 0.6
    for plane, channel in zip(chroma_planes(planes, (width, height)), (1, 2), strict=True):
        # measured: 0.55 and 0.39; the odd tiles' chroma left unshifted: 0.88 and 1.25, shifted a pixel: 0.97, 1.29
        assert np.abs(plane - block_means(expected[..., channel])).mean() < 0.7, channel


def test_a_decoded_picture_back_to_rgb_is_jfif_with_each_chroma_sample_over_its_block() -> None:
    """rgb_of_yuv420 against the JFIF conversion written out pixel by pixel (each pixel's Cb and Cr
    its 2×2 block's sample), rounded: equal; a grey frame comes back exactly through
    compose_yuv420; decoded_planes of a decoded yuvj420p picture are the planes coded losslessly."""
    rng = np.random.default_rng(7)
    width, height = 37, 21
    coded_w, coded_h = coded_size((width, height))
    planes = rng.integers(0, 256, (coded_h * 3 // 2, coded_w), dtype=np.uint8)
    cb, cr = (plane.astype(np.float64) - 128.0 for plane in chroma_planes(planes, (coded_w, coded_h)))
    cb, cr = (np.repeat(np.repeat(c, 2, axis=0), 2, axis=1) for c in (cb, cr))
    y = planes[:coded_h].astype(np.float64)
    expected = np.stack([y + 1.402 * cr, y - 0.344136 * cb - 0.714136 * cr, y + 1.772 * cb], axis=-1)
    expected = np.clip(np.floor(expected + 0.5), 0, 255).astype(np.uint8)[:height, :width]
    assert np.array_equal(rgb_of_yuv420(planes, (width, height)), expected)
    grey = np.repeat(rng.integers(0, 256, (height, width, 1), dtype=np.uint8), 3, axis=-1)
    picture = compose_yuv420((width, height), [(Rect(0, 0, width, height), Codec.RAW, 0, grey.tobytes())])
    assert np.array_equal(rgb_of_yuv420(picture, (width, height)), grey)
    encoder = av.CodecContext.create("libx264", "w")
    encoder.width, encoder.height, encoder.pix_fmt, encoder.color_range = coded_w, coded_h, "yuv420p", 2
    encoder.time_base, encoder.options = Fraction(1, 25), {"preset": "ultrafast", "qp": "0", "tune": "zerolatency"}
    encoder.open()
    frame = av.VideoFrame.from_ndarray(planes, format="yuv420p")
    frame.pts, frame.color_range = 0, 2
    decoder = av.CodecContext.create("h264", "r")
    decoded = [p for packet in [*encoder.encode(frame), *encoder.encode(None)] for p in decoder.decode(packet)]
    assert len(decoded) == 1 and decoded[0].format.name == "yuvj420p"
    assert np.array_equal(decoded_planes(decoded[0]), planes)


def test_a_tile_that_is_not_what_its_rect_says_is_refused() -> None:
    payload = encode(np.zeros((8, 8, 3), np.uint8), Codec.JPEG, 80)
    with pytest.raises(ValueError, match="JPEG tile is 8x8, expected 16x8"):
        tile_planes(payload, Codec.JPEG, 16, 8)
    with pytest.raises(ValueError, match="JPEG tile does not decode"):
        tile_planes(b"not a jpeg", Codec.JPEG, 16, 8)


def report(decode_queue: float = 0.0, dropped: float = 0.0, frame: int | None = None) -> StreamReport:
    return StreamReport(bytes_per_s=1e5, decoded_fps=30.0, decode_queue=decode_queue, frames_dropped=dropped,
                        frame=frame)


def test_feedback_no_page_sends_is_refused_with_the_reason() -> None:
    guard = FeedbackGuard(0.0)
    assert guard.report(report(), frames_sent=0, newest_sent=None) is None
    assert guard.report(report(dropped=5.0, frame=41), frames_sent=10, newest_sent=41) is None
    assert "went down, from 5 to 4" in guard.report(report(dropped=4.0), 10, 41)
    assert "is more than the 10 video frames" in FeedbackGuard(0.0).report(report(dropped=11.0), 10, 41)
    assert "longer than any decoder's" in FeedbackGuard(0.0).report(report(decode_queue=1e9), 10, 41)
    assert "frame 42 was never sent" in FeedbackGuard(0.0).report(report(frame=42), 10, 41)
    assert "frame 0 was never sent to this viewer (newest sent: None)" in FeedbackGuard(0.0).report(
        report(frame=0), 0, None)


def test_a_keyframe_flood_and_malformed_feedback_again_and_again_are_refused() -> None:
    guard = FeedbackGuard(0.0)
    assert all(guard.keyframe(0.0) is None for _ in range(KEYFRAME_BURST))
    assert "keyframe requests faster than" in guard.keyframe(0.0)
    assert guard.keyframe(1.0) is None                       # a second later: KEYFRAME_RATE more
    assert [guard.malformed_message() for _ in range(MAX_MALFORMED)][-1] == f"{MAX_MALFORMED} malformed messages"
    assert FeedbackGuard(0.0).malformed_message() is None
