"""What the coordinator's stream thread can afford per frame (issue 21), in pixels: a frame of at
most :data:`FULL_ANALYSIS_PIXELS` is encoded from raw tiles (local nodes, every viewer on video) with
x264's fuller analysis (:data:`server.video_encoder.X264_PARAMS`); a larger one from JPEG tiles with
CABAC alone. Measured on the 2-core machine (``python -m bench.stream``): at 1280×720 the fuller
path takes 4.2 ms to encode and 4.5–6 ms to compose (raw tiles converted in float32) and saves 40 %
of the bytes at the tiles' PSNR; at 1920×1080 (``--synthetic``) it took 10.9 + 13.5 ms, so the stream
fell from 54 to 28 frames a second, where JPEG tiles and the lighter options take 5.7 + 4.7 ms.
"""

#: The largest frame (pixels) encoded from raw tiles with the fuller analysis: 1280×720.
FULL_ANALYSIS_PIXELS = 1280 * 720


def full_analysis(size: tuple[int, int]) -> bool:
    """Whether frames of ``size`` (w, h px) get the raw source and the fuller analysis."""
    return size[0] * size[1] <= FULL_ANALYSIS_PIXELS
