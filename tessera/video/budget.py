"""What the coordinator's stream thread can afford per frame (issue 21), in pixels: a frame of at
most :data:`FULL_ANALYSIS_PIXELS` is encoded from raw tiles (local nodes, every viewer on video) with
x264's fuller analysis (:data:`server.video_encoder.X264_PARAMS`); a larger one from JPEG tiles with
CABAC alone. The limit is where the fuller path's encode and compose time still fits a live frame
rate on a 2-core machine (``python -m bench.stream``; see the design notes).
"""

#: The largest frame (pixels) encoded from raw tiles with the fuller analysis: 1280×720.
FULL_ANALYSIS_PIXELS = 1280 * 720


def full_analysis(size: tuple[int, int]) -> bool:
    """Whether frames of ``size`` (w, h px) get the raw source and the fuller analysis."""
    return size[0] * size[1] <= FULL_ANALYSIS_PIXELS
