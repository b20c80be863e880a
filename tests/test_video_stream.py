"""Video to the browser (issue 21) on the coordinator, without network: the encoder on real
renders (decoded again with PyAV), and a session's viewers on one stream — keyframes for a new
viewer, a viewer whose socket falls behind skips to a keyframe, stills stay images."""

from __future__ import annotations

import asyncio
import math
import time

import av
import numpy as np
import pytest

from bench.images import psnr
from node.gl.renderer import TileRenderer
from node.scene.loading import load_scene
from server.frame_store import PublishedFrame
from server.video_encoder import X264_LIGHT_PARAMS, X264_PARAMS, VideoEncoder
from server.video_stream import VIDEO_SOURCE_QUALITY, VideoStream, default_bitrate
from server.viewers import MAX_UNACKNOWLEDGED, MAX_VIDEO_QUEUED, ViewerHub, ViewerSlot
from tessera.geometry import Camera, Rect, default_camera
from tessera.video.link_rate import DECREASE, LinkReport
from tessera.video.yuv_frame import compose_yuv420
from tessera.wire.codec import Codec, encode
from tessera.wire.protocol import unpack_frame
from tessera.wire.stream_messages import StreamReport
from tessera.wire.video import VideoCodec, is_video, pack_video, unpack_video

SIZE = (321, 181)
DECODERS = {VideoCodec.H264: "h264", VideoCodec.VP9: "vp9"}


@pytest.fixture(scope="module")
def renders(ctx) -> list[np.ndarray]:
    """Eight frames of the default scene, the camera turning 2° a frame: (h, w, 3) uint8 each."""
    scene = load_scene("builtin:cluster")
    renderer = TileRenderer(ctx, scene)
    start = default_camera(scene.bounds)
    eye, target = np.asarray(start.eye), np.asarray(start.target)
    frames = []
    for step in range(8):
        angle = math.radians(2.0 * step)
        offset = eye - target
        turned = (target[0] + math.cos(angle) * offset[0] + math.sin(angle) * offset[2], eye[1],
                  target[2] - math.sin(angle) * offset[0] + math.cos(angle) * offset[2])
        camera = Camera(eye=tuple(float(v) for v in turned), target=start.target, fovy_deg=start.fovy_deg)
        frames.append(renderer.render_frame(camera, SIZE, scene.state_at(0.0, None)).pixels.copy())
    return frames


def tiles_of(pixels: np.ndarray) -> list[tuple[Rect, Codec, int, bytes]]:
    """Two JPEG tiles at the video source quality, split at an odd column as a balancer may."""
    height, width = pixels.shape[:2]
    rects = [Rect(0, 0, 157, height), Rect(157, 0, width - 157, height)]
    return [(rect, Codec.JPEG, slot, encode(np.ascontiguousarray(pixels[rect.y:rect.y1, rect.x:rect.x1]), Codec.JPEG,
                                            VIDEO_SOURCE_QUALITY)) for slot, rect in enumerate(rects)]


@pytest.mark.gl
@pytest.mark.parametrize("codec", list(VideoCodec))
def test_encoded_renders_decode_to_the_renders(renders, codec: VideoCodec) -> None:
    encoder = VideoEncoder(codec, SIZE, default_bitrate(codec, SIZE, 30.0, 8e6) * 4, 30.0)
    decoder = av.CodecContext.create(DECODERS[codec], "r")
    keys, quality = [], []
    for index, pixels in enumerate(renders):
        units = encoder.encode(compose_yuv420(SIZE, tiles_of(pixels)), keyframe=index == 5)
        assert len(units) == 1
        data, keyframe = units[0]
        keys.append(keyframe)
        pictures = decoder.decode(av.Packet(data))
        assert len(pictures) == 1
        decoded = pictures[0].to_ndarray(format="rgb24")[:SIZE[1], :SIZE[0]]
        quality.append(psnr(decoded, pixels))
    assert keys == [True, False, False, False, False, True, False, False]
    assert min(quality) >= 33.0, quality      # full range in, full range out: a range mix-up is ~25 dB


def frame(frame_id: int, pixels: np.ndarray, still: bool = False, inputs: dict | None = None) -> PublishedFrame:
    return PublishedFrame(frame_id, Camera(eye=(0, 0, 5), target=(0, 0, 0)), SIZE, tiles_of(pixels), time.monotonic(),
                          still=still, inputs=inputs or {})


def _next(slot: ViewerSlot) -> str | bytes:
    """The message ``slot``'s sender would send next (one is waiting)."""
    if slot.control:
        return slot.control.popleft()
    if slot.video:
        return slot.video.popleft()
    message, slot.frame = slot.frame, None
    assert message is not None
    return message


async def encoded(hub: ViewerHub, codec: VideoCodec, count: int) -> None:
    """Wait until the hub's stream has encoded ``count`` frames."""
    for _ in range(400):
        if hub.streams[codec].frames_encoded >= count:
            return
        await asyncio.sleep(0.01)
    raise AssertionError(f"the stream encoded {hub.streams[codec].frames_encoded} frames, not {count}")


@pytest.mark.gl
@pytest.mark.gl
def test_h264_from_raw_tiles_is_main_profile_with_cabac_and_larger_frames_get_the_lighter_options(renders) -> None:
    """Raw tiles (a video-only session's, from local nodes) in: a Main-profile stream with CABAC
    (the PPS's entropy coding flag), every frame within 38 dB of its render; a frame over 1280×720
    is encoded with the lighter options."""
    encoder = VideoEncoder(VideoCodec.H264, SIZE, default_bitrate(VideoCodec.H264, SIZE, 30.0, 8e6) * 4, 30.0)
    assert encoder.options["x264-params"] == X264_PARAMS
    decoder = av.CodecContext.create("h264", "r")
    stream, quality = b"", []
    for index, pixels in enumerate(renders):
        raw = [(Rect(0, 0, *SIZE), Codec.RAW, 0, pixels.tobytes())]
        (data, _), = encoder.encode(compose_yuv420(SIZE, raw), keyframe=index == 0)
        stream += data
        (picture,) = decoder.decode(av.Packet(data))
        quality.append(psnr(picture.to_ndarray(format="rgb24")[:SIZE[1], :SIZE[0]], pixels))
    sps, pps = stream.index(b"\x00\x00\x01\x67"), stream.index(b"\x00\x00\x01\x68")
    assert stream[sps + 4] == 0x4D, "Main profile"
    assert stream[pps + 4] & 0x20, "entropy_coding_mode_flag (CABAC) after pps_id 0 and sps_id 0"
    assert min(quality) >= 38.0, quality
    large = VideoEncoder(VideoCodec.H264, (1282, 720), 4e6, 30.0)
    assert large.options["x264-params"] == X264_LIGHT_PARAMS


def test_viewers_of_one_stream_keyframes_skips_and_stills(renders) -> None:
    async def scenario() -> None:
        hub = ViewerHub()
        first, tiles_viewer = hub.join(), hub.join()
        choice = hub.start_video(first, VideoCodec.H264, SIZE, 8e6, 60.0)
        assert (choice.transport, choice.codec) == ("h264", "avc1.4d401e")
        hub.publish_frame(frame(1, renders[0], inputs={first.viewer_id: 7}))
        await encoded(hub, VideoCodec.H264, 1)
        video = unpack_video(_next(first))                       # type: ignore[arg-type]
        assert (video.frame_id, video.keyframe, video.input_seq) == (1, True, 7)
        assert unpack_frame(_next(tiles_viewer)).frame_id == 1   # type: ignore[arg-type]

        second = hub.join()
        hub.start_video(second, VideoCodec.H264, SIZE, 8e6, 60.0)
        hub.publish_frame(frame(2, renders[1]))
        await encoded(hub, VideoCodec.H264, 2)
        assert unpack_video(_next(second)).keyframe              # type: ignore[arg-type]
        assert unpack_video(_next(first)).frame_id == 2          # type: ignore[arg-type]

        # the first viewer stops reading: its queue overflows, it waits for a keyframe, which comes
        for index in range(3, 4 + MAX_VIDEO_QUEUED):
            hub.publish_frame(frame(index, renders[index % 8]))
            await encoded(hub, VideoCodec.H264, index)
        assert first.needs_keyframe and not first.video
        assert not any(unpack_video(message).keyframe for message in second.video)   # no keyframe it did not need
        second.video.clear()
        index = 4 + MAX_VIDEO_QUEUED
        hub.publish_frame(frame(index, renders[index % 8]))
        await encoded(hub, VideoCodec.H264, index)
        resumed = unpack_video(_next(first))                     # type: ignore[arg-type]
        assert resumed.keyframe and resumed.frame_id == index and not first.needs_keyframe

        # a still frame is an image for everyone; the stream does not encode it
        hub.publish_frame(frame(index + 1, renders[0], still=True))
        await asyncio.sleep(0.05)
        assert hub.streams[VideoCodec.H264].frames_encoded == index
        for slot in (first, second, tiles_viewer):
            message = _next(slot)
            while isinstance(message, bytes) and is_video(message):
                message = _next(slot)
            assert unpack_frame(message).still                   # type: ignore[arg-type]

        hub.leave(first)
        assert VideoCodec.H264 in hub.streams
        hub.leave(second)
        assert not hub.streams

    asyncio.run(scenario())


def test_a_congested_window_of_few_pictures_keeps_the_bits_a_picture_got_through(renders) -> None:
    """The stream counts the pictures it encodes for its rate control: three in a window of 1.5 s
    (2 a second) that delivered 20 kbit/s leave a cap of 0.7 x 10 kbit a picture at the nominal
    60 fps, not 0.7 x 20 kbit/s (before, the 200 kbit/s floor; at 720p a picture decoded to ~10 dB)."""
    async def scenario() -> None:
        delivered: list[int] = []
        stream = VideoStream(VideoCodec.H264, SIZE, 8e6, 60.0,
                             lambda _, encoded: delivered.append(encoded.frame.frame_id))
        stream.rate.update([LinkReport(delivered_bps=1e6, dropped=0, decode_queue=0.0, backlog=0)], 0.0)
        for index in range(3):
            stream.submit(frame(index + 1, renders[index]))
            for _ in range(400):
                if len(delivered) > index:
                    break
                await asyncio.sleep(0.01)
        assert delivered == [1, 2, 3]
        assert stream.rate.update([LinkReport(delivered_bps=20e3, dropped=1, decode_queue=0.0, backlog=0)], 1.5)
        assert stream.rate.bitrate == pytest.approx(DECREASE * 20e3 / 2.0 * 60.0)
        stream.close()

    asyncio.run(scenario())


def test_a_video_viewer_that_never_reports_does_not_grow_the_coordinators_memory() -> None:
    async def scenario() -> None:
        slot = ViewerSlot()
        slot.video_codec = VideoCodec.H264
        message = pack_video(1, SIZE, VideoCodec.H264, True, b"unit")
        for _ in range(MAX_UNACKNOWLEDGED + 50):
            slot.put_video(message, True)
            assert await slot.next_message() == message
        assert slot.video_written == len(message) * (MAX_UNACKNOWLEDGED + 50)
        assert len(slot._written_at) == MAX_UNACKNOWLEDGED

    asyncio.run(scenario())


def test_a_video_viewers_queue_delay_is_how_long_its_oldest_frame_not_received_has_been_on_its_way() -> None:
    async def scenario() -> None:
        slot = ViewerSlot()
        slot.video_codec = VideoCodec.H264
        for frame_id in (1, 2, 3):
            slot.put_video(pack_video(frame_id, SIZE, VideoCodec.H264, frame_id == 1, b"unit"), frame_id == 1)
            await slot.next_message()
        written = time.monotonic()

        def report(frame: int) -> StreamReport:
            return StreamReport(bytes_per_s=0.0, decoded_fps=0.0, decode_queue=0.0, frames_dropped=0.0, frame=frame)

        slot.take_report(report(1), written + 0.5)          # frames 2 and 3 are still on their way
        link = slot.link_report(written + 0.9)
        assert 0.5 <= link.in_flight_s < 5.0 and link.congested
        slot.take_report(report(3), written + 1.0)
        assert slot.link_report(written + 1.1).in_flight_s == 0.0

    asyncio.run(scenario())
