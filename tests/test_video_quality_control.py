"""The H.264 stream's CRF loop (issue 37, part 3), pure: PSNRs of a modelled encoder in, a CRF out.
The model is the measured shape (PSNR falls linearly with CRF, 0.1-1.0 dB a unit, frames scatter
about it); the loop must reach the tiles' PSNR, stay within its bounds and then hold still."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tessera.video.quality_control import BAND_DB, CRF_RANGE, WINDOW, CrfControl


def run(control: CrfControl, intercept: float, slope: float, tiles: float, noise: float, windows: int,
        seed: int) -> list[float]:
    """Feed ``windows`` windows of the model video PSNR = ``intercept`` − ``slope`` · CRF against
    ``tiles`` dB, each frame off by N(0, ``noise``) dB; the CRF after each window."""
    rng = np.random.default_rng(seed)
    crfs = []
    for _ in range(windows * WINDOW):
        video = intercept - slope * control.crf + rng.normal(0.0, noise)
        control.observe(video, tiles + rng.normal(0.0, noise))
        if control.measured % WINDOW == 0:
            crfs.append(control.crf)
    return crfs


plants = st.tuples(st.floats(0.12, 0.9), st.floats(20.0, 34.0), st.floats(36.0, 46.0), st.floats(22.0, 32.0),
                   st.integers(0, 2**31))


@settings(max_examples=60, deadline=None)
@given(plants)
def test_the_crf_converges_to_where_the_video_matches_the_tiles_and_then_holds(plant) -> None:
    slope, ideal, tiles, start, seed = plant
    intercept = tiles + slope * ideal   # the model's video equals the tiles at CRF ``ideal``
    control = CrfControl(start)
    crfs = run(control, intercept, slope, tiles, noise=0.05, windows=60, seed=seed)
    assert all(CRF_RANGE[0] <= crf <= CRF_RANGE[1] for crf in crfs)
    settled = crfs[30:]
    # within the band (and the noise of a window's mean) of the matching CRF, for good
    for crf in settled:
        assert abs(intercept - slope * crf - tiles) <= BAND_DB + 0.2, (crf, ideal, slope)
    # no pumping: after settling the CRF moves rarely and within a narrow range
    moves = sum(a != b for a, b in itertools.pairwise(settled))
    assert moves <= 3, settled
    assert max(settled) - min(settled) <= 2 * (BAND_DB + 0.2) / slope + 0.5, settled


@settings(max_examples=40, deadline=None)
@given(plants)
def test_it_converges_within_a_few_windows_from_the_default(plant) -> None:
    slope, ideal, tiles, _, seed = plant
    control = CrfControl(28.5)
    crfs = run(control, tiles + slope * ideal, slope, tiles, noise=0.05, windows=16, seed=seed)
    assert abs(slope * (crfs[-1] - ideal)) <= BAND_DB + 0.2, (crfs, ideal, slope)


@pytest.mark.parametrize(("ideal", "bound"), [(10.0, CRF_RANGE[0]), (45.0, CRF_RANGE[1])])
def test_a_target_out_of_reach_stops_at_the_bound_it_heads_for(ideal: float, bound: float) -> None:
    control = CrfControl(28.5)
    crfs = run(control, 40.0 + 0.4 * ideal, 0.4, 40.0, noise=0.02, windows=30, seed=1)
    assert crfs[-1] == bound and all(CRF_RANGE[0] <= crf <= CRF_RANGE[1] for crf in crfs)
    changes = control.changes
    run(control, 40.0 + 0.4 * ideal, 0.4, 40.0, noise=0.02, windows=10, seed=2)
    assert control.changes == changes   # pinned at the bound: no more changes (and keyframes)


def test_the_slope_is_learnt_from_the_windows_either_side_of_a_change() -> None:
    control = CrfControl(28.0)
    run(control, 40.0 + 0.9 * 20.0, 0.9, 40.0, noise=0.0, windows=3, seed=0)
    assert control.slope_db > 0.6   # started at 0.45, the plant's is 0.9


def test_frames_either_codec_codes_exactly_tell_nothing() -> None:
    control = CrfControl(28.5)
    for _ in range(3 * WINDOW):
        assert control.observe(math.inf, 40.0) is None
        assert control.observe(41.0, math.inf) is None
    assert control.measured == 0 and control.crf == 28.5


def test_a_window_inside_the_band_changes_nothing_and_one_outside_moves_the_right_way() -> None:
    control = CrfControl(28.5)
    for _ in range(WINDOW):
        control.observe(40.0 + BAND_DB / 2, 40.0)
    assert control.crf == 28.5 and control.changes == 0
    results = [control.observe(41.0, 40.0) for _ in range(WINDOW)]
    assert results[:-1] == [None] * (WINDOW - 1) and results[-1] is not None and results[-1] > 28.5
    raised = control.crf
    results = [control.observe(39.0, 40.0) for _ in range(WINDOW)]
    assert results[-1] is not None and results[-1] < raised and control.changes == 2


def test_bounds_are_checked_and_the_start_is_clamped() -> None:
    with pytest.raises(ValueError, match="lowest <= highest"):
        CrfControl(28.0, lowest=30.0, highest=20.0)
    assert CrfControl(50.0).crf == CRF_RANGE[1]
