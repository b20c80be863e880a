"""The H.264 stream's CRF loop (issue 37, part 3), pure: PSNRs of a modelled encoder in, a CRF out.
The model is the measured shape (PSNR falls about linearly with CRF, 0.1-1.0 dB a unit; the
frames scatter about it, 0.3 dB measured live, neighbours alike); from any start within its bounds
the loop must settle where the video matches the tiles, stay within its bounds, and then hold still.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from tessera.video.quality_control import (
    BAND_DB,
    CRF_RANGE,
    DECIDE_EVERY,
    HISTORY,
    MIN_SAMPLES,
    NOISE_FLOOR_DB,
    QUANTUM,
    TARGET_DB,
    Z_ABOVE,
    Z_BELOW,
    CrfLoop,
    observe,
    restarted,
)

TILES_DB = 40.0


@dataclass
class Plant:
    """A modelled encoder: the video's PSNR is the tiles' at CRF ``ideal`` (plus the loop's
    target), ``slope`` dB less a CRF unit above it; each frame off by ``noise`` dB (standard
    deviation), a frame's deviation ``rho`` of its predecessor's (neighbouring frames look alike)."""

    slope: float
    ideal: float
    noise: float = 0.0
    rho: float = 0.0

    def surplus(self, crf: float) -> float:
        """The true surplus of the video over the loop's target at ``crf`` (dB)."""
        return self.slope * (self.ideal - crf)


def run(loop: CrfLoop, plant: Plant, frames: int, seed: int) -> tuple[CrfLoop, list[CrfLoop]]:
    """Feed ``frames`` measurements of ``plant`` at the loop's CRF; the loop after each."""
    rng = np.random.default_rng(seed)
    deviation, history = 0.0, []
    for _ in range(frames):
        deviation = plant.rho * deviation + math.sqrt(1.0 - plant.rho ** 2) * plant.noise * rng.normal()
        loop = observe(loop, TILES_DB + TARGET_DB + plant.surplus(loop.crf) + deviation, TILES_DB, loop.crf)
        history.append(loop)
    return loop, history


def first_settled(history: list[CrfLoop]) -> int:
    """The index of the first measurement after which the loop held its CRF (fails if none)."""
    index = next((i for i, loop in enumerate(history) if loop.settled), None)
    assert index is not None, [loop.crf for loop in history[::DECIDE_EVERY]]
    return index


#: The most measurements from a start anywhere within the bounds to the first hold: 6 steps of
#: the first decision's samples, and as many of single decisions on top.
SETTLE_WITHIN = 6 * MIN_SAMPLES + 6 * DECIDE_EVERY + 5 * MIN_SAMPLES
#: Where a loop may hold on a plant without scatter (dB of true surplus): the band, widened by the
#: standard error the loop assumes at the least (the noise floor, over the first decision's samples).
QUIET_HOLD = (-(BAND_DB + Z_BELOW * NOISE_FLOOR_DB / math.sqrt(MIN_SAMPLES / DECIDE_EVERY)),
              BAND_DB + Z_ABOVE * NOISE_FLOOR_DB / math.sqrt(MIN_SAMPLES / DECIDE_EVERY))

slopes = st.floats(0.1, 1.0)
inside = st.floats(CRF_RANGE[0] + 0.5, CRF_RANGE[1] - 0.5)
starts = st.floats(*CRF_RANGE)
seeds = st.integers(0, 2**31)


@settings(max_examples=150, deadline=None)
@given(slopes, inside, starts, seeds)
# a steep plant the first guess of the slope overshoots: steps of 0.5 either way, both outside the band
@example(1.0, 28.12, 28.5, 0)
def test_from_any_start_it_settles_where_the_video_matches_the_tiles_and_holds(slope, ideal, start, seed) -> None:
    plant = Plant(slope, ideal)
    loop, history = run(CrfLoop(start), plant, 400, seed)
    settled = first_settled(history)
    assert settled <= SETTLE_WITHIN, (settled, [s.crf for s in history[::DECIDE_EVERY]])
    assert all(CRF_RANGE[0] <= s.crf <= CRF_RANGE[1] for s in history)
    assert all(s.crf % QUANTUM == 0 for s in history if s.changes)
    # held within the band (widened by the least error assumed), and for good: more samples narrow
    # the error, so a hold may still move, within that band, twice at most
    assert all(QUIET_HOLD[0] <= plant.surplus(s.crf) <= QUIET_HOLD[1] for s in history[settled:]), (loop, plant)
    assert loop.changes - history[settled].changes <= 2, [s.crf for s in history[settled::DECIDE_EVERY]]
    assert loop.settled


# Scatter makes this a statistical property: its examples are fixed (derandomize), so a run cannot
# draw one from the far tail. Over 8000 random plants of this range (a quarter at its worst corner)
# the most changes after the first hold were 6, the true surplus over the last third -0.47..+0.58 dB.
@settings(max_examples=150, deadline=None, derandomize=True)
@given(slopes, inside, starts, st.floats(0.05, 0.3), st.floats(0.0, 0.5), seeds)
def test_frames_that_scatter_as_measured_live_move_it_rarely_once_settled(slope, ideal, start, noise, rho,
                                                                         seed) -> None:
    """Scatter up to 0.3 dB a frame, neighbours alike (half of a frame's deviation is its
    predecessor's): it still settles, near the match, and then moves at most a few times in 600
    measurements (each move costs a keyframe)."""
    plant = Plant(slope, ideal, noise, rho)
    loop, history = run(CrfLoop(start), plant, 600, seed)
    settled = first_settled(history)
    assert settled <= 2 * SETTLE_WITHIN and all(CRF_RANGE[0] <= s.crf <= CRF_RANGE[1] for s in history)
    assert loop.changes - history[settled].changes <= 8, [s.crf for s in history[settled::DECIDE_EVERY]]
    for s in history[400:]:
        assert -0.8 <= plant.surplus(s.crf) <= 0.9, (s.crf, plant)


@settings(max_examples=60, deadline=None)
@given(slopes, st.sampled_from([CRF_RANGE[0] - 6.0, CRF_RANGE[1] + 6.0]), starts, seeds)
def test_a_match_out_of_reach_parks_the_crf_at_the_bound_it_heads_for(slope, ideal, start, seed) -> None:
    loop, history = run(CrfLoop(start), Plant(slope, ideal, noise=0.1), 300, seed)
    bound = CRF_RANGE[0] if ideal < CRF_RANGE[0] else CRF_RANGE[1]
    settled = first_settled(history)
    assert history[settled].crf == loop.crf == bound and loop.settled
    assert loop.changes == history[settled].changes   # parked: no more changes (and keyframes)


# Scatter (0.1 dB) makes this statistical too: fixed examples (derandomize), as above.
@settings(max_examples=60, deadline=None, derandomize=True)
@given(slopes, inside, inside, starts, seeds)
# the match 0.05 CRF units from where the loop held, its surplus at the threshold: a late scatter
# may still take it one quantum on, which it then holds
@example(0.484375, 26.25, 26.4453125, 18.0, 285)
def test_when_the_match_moves_the_loop_follows(slope, ideal, moved, start, seed) -> None:
    """A camera that turns to other content: the CRF that matches moves, and the loop settles again
    near it (a hold near the band's edge may still take one more step: it holds again after it)."""
    loop, _ = run(CrfLoop(start), Plant(slope, ideal, noise=0.1), 250, seed)
    loop, history = run(loop, Plant(slope, moved, noise=0.1), 400 + MIN_SAMPLES, seed + 1)
    settled = first_settled(history)
    assert settled <= 2 * SETTLE_WITHIN, (settled, [s.crf for s in history[::DECIDE_EVERY]])
    assert QUIET_HOLD[0] - 0.2 <= Plant(slope, moved).surplus(loop.crf) <= QUIET_HOLD[1] + 0.2, (loop, moved)
    assert any(s.settled for s in history[-MIN_SAMPLES - DECIDE_EVERY:]), [s.crf for s in history[::DECIDE_EVERY]]


def test_a_slope_off_the_first_guess_is_learnt_from_a_large_change() -> None:
    loop, _ = run(CrfLoop(28.0), Plant(0.9, 20.0), MIN_SAMPLES + MIN_SAMPLES, 0)
    assert loop.changes >= 1 and loop.slope_db > 0.6   # started at 0.45, the plant's is 0.9


def test_measurements_of_frames_at_another_crf_are_left_out() -> None:
    """A frame encoded before a change is measured after it: it tells nothing of the new CRF."""
    loop = CrfLoop(28.5)
    for _ in range(3 * MIN_SAMPLES):
        loop = observe(loop, 30.0, TILES_DB, 26.0)
    assert loop.measured == 0 and loop.crf == 28.5 and not loop.samples


def test_frames_either_codec_codes_exactly_tell_nothing() -> None:
    loop = CrfLoop(28.5)
    for _ in range(3 * MIN_SAMPLES):
        loop = observe(loop, math.inf, TILES_DB, 28.5)
        loop = observe(loop, 41.0, math.inf, 28.5)
    assert loop.measured == 0 and loop.crf == 28.5


def test_no_decision_before_enough_samples_and_one_outside_the_band_moves_the_right_way() -> None:
    loop = CrfLoop(28.5)
    for _ in range(MIN_SAMPLES - 1):
        loop = observe(loop, TILES_DB + TARGET_DB + 3.0, TILES_DB, 28.5)
    assert loop.crf == 28.5 and not loop.settled
    loop = observe(loop, TILES_DB + TARGET_DB + 3.0, TILES_DB, 28.5)
    assert loop.crf > 28.5 and loop.changes == 1 and not loop.samples   # sharper than the tiles: fewer bits
    raised = loop.crf
    for _ in range(MIN_SAMPLES):
        loop = observe(loop, TILES_DB + TARGET_DB - 3.0, TILES_DB, raised)
    assert loop.crf < raised and loop.changes == 2


def test_a_mean_within_the_band_holds_and_says_so() -> None:
    loop = CrfLoop(28.5)
    for i in range(HISTORY):
        loop = observe(loop, TILES_DB + TARGET_DB + (0.1 if i % 2 else -0.1), TILES_DB, 28.5)
    assert loop.crf == 28.5 and loop.settled and loop.changes == 0 and abs(loop.surplus_db or 0.0) < 1e-9


def test_a_restart_keeps_the_crf_and_measures_again() -> None:
    loop, _ = run(CrfLoop(28.5), Plant(0.5, 25.0), 80, 0)
    again = restarted(loop)
    assert (again.crf, again.slope_db, again.changes) == (loop.crf, loop.slope_db, loop.changes)
    assert not again.samples and not again.settled


def test_bounds_are_checked_and_the_start_is_clamped() -> None:
    with pytest.raises(ValueError, match="lowest <= highest"):
        CrfLoop(28.0, lowest=30.0, highest=20.0)
    assert CrfLoop(50.0).crf == CRF_RANGE[1]
